// Records the viewer's 3D view as WebM, or takes a screenshot of the page as PNG at model
// time T: node record.mjs URL OUT.webm|OUT.png [FPS] [WxH] [T]
// (tools/cvt_view.py --video / --screenshot starts the server and calls this).
import { writeFileSync } from "node:fs";
import { openViewer } from "./browser.js";

const [url, out, fps = "30", size = "1280x720", at = ""] = process.argv.slice(2);
if (!url || !out) {
  console.error("usage: node record.mjs URL OUT.webm|OUT.png [FPS] [WxH] [T]");
  process.exit(2);
}
const [width, height] = size.split("x").map(Number);
const { browser, page } = await openViewer(url, { width, height });
const frames = await page.evaluate(() => window.cvtView.frames);
if (out.endsWith(".png")) {
  const s = await page.evaluate((t) => {
    const v = window.cvtView, s = t === "" ? v.frames - 1 : v.frameAt(Number(t));
    v.show(s);
    return s;
  }, at);
  await page.screenshot({ path: out });
  await browser.close();
  console.log(`cvt_view: snapshot ${s + 1} of ${frames} into ${out}`);
  process.exit(0);
}
const t0 = Date.now();
const b64 = await page.evaluate((f) => window.cvtView.recordBase64(f), Number(fps));
await browser.close();
writeFileSync(out, Buffer.from(b64, "base64"));
console.log(`cvt_view: ${frames} snapshots at ${fps} frames per second into ${out} ` +
            `(${(Buffer.byteLength(b64, "base64") / 1e6).toFixed(2)} MB, ${((Date.now() - t0) / 1e3).toFixed(1)} s)`);
