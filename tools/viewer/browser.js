// Debian's Chromium, headless, driven by playwright-core (the browser test and record.mjs).
// WebGL runs on SwiftShader (software): no GPU needed.
import { chromium } from "playwright-core";

export const CHROMIUM = process.env.CHROMIUM || "/usr/bin/chromium";

export async function openViewer(url, { width = 1280, height = 720 } = {}) {
  const browser = await chromium.launch({
    executablePath: CHROMIUM,
    args: ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist", "--no-sandbox"],
  });
  const page = await browser.newPage({ viewport: { width, height } });
  const log = [];
  page.on("console", (m) => log.push(`${m.type()}: ${m.text()}`));
  page.on("pageerror", (e) => log.push(`pageerror: ${e.message}`));
  await page.goto(url);
  await page.waitForFunction(() => window.cvtView && (window.cvtView.ready || window.cvtView.error), null,
                             { timeout: 120000 });
  const error = await page.evaluate(() => window.cvtView.error);
  if (error) {
    await browser.close();
    throw new Error(`the viewer says: ${error}\n${log.join("\n")}`);
  }
  return { browser, page, log };
}
