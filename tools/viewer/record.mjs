// Records the viewer's 3D view as WebM: node record.mjs URL OUT.webm [FPS] [WxH]
// (tools/cvt_view.py --video starts the server and calls this).
import { writeFileSync } from "node:fs";
import { openViewer } from "./browser.js";

const [url, out, fps = "30", size = "1280x720"] = process.argv.slice(2);
if (!url || !out) {
  console.error("usage: node record.mjs URL OUT.webm [FPS] [WxH]");
  process.exit(2);
}
const [width, height] = size.split("x").map(Number);
const { browser, page } = await openViewer(url, { width, height });
const frames = await page.evaluate(() => window.cvtView.frames);
const t0 = Date.now();
const b64 = await page.evaluate((f) => window.cvtView.recordBase64(f), Number(fps));
await browser.close();
writeFileSync(out, Buffer.from(b64, "base64"));
console.log(`cvt_view: ${frames} snapshots at ${fps} frames per second into ${out} ` +
            `(${(Buffer.byteLength(b64, "base64") / 1e6).toFixed(2)} MB, ${((Date.now() - t0) / 1e3).toFixed(1)} s)`);
