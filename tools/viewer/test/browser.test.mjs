// The viewer in a real browser (Debian's Chromium, headless, WebGL on SwiftShader) on a
// short run of the mini model: the chain is drawn where the snapshot puts it, the colours
// of the tension scale are on the screen, the slider moves the chain, and a recorded video
// plays. Needs CVT_ENGINE_EXE (ctest sets it). Screenshots go to VIEWER_SHOTS (default: a
// temporary folder, printed).
import { test, before, after } from "node:test";
import assert from "node:assert/strict";
import { execFileSync, spawn } from "node:child_process";
import { mkdtempSync, mkdirSync, readFileSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";
import { PNG } from "pngjs";
import { colormap } from "../data.js";
import { openViewer } from "../browser.js";

const HERE = dirname(fileURLToPath(import.meta.url));
const ROOT = join(HERE, "..", "..", "..");
const EXE = process.env.CVT_ENGINE_EXE || join(ROOT, "build", "cvt-engine");
const dir = mkdtempSync(join(tmpdir(), "cvt-viewer-browser-"));
const SHOTS = process.env.VIEWER_SHOTS || dir;
mkdirSync(SHOTS, { recursive: true });
const BG = [0x1e, 0x22, 0x28];
let server, url, browser, page;

function startServer(file) {
  return new Promise((resolve, reject) => {
    const p = spawn("/usr/bin/python3", [join(ROOT, "tools", "cvt_view.py"), file, "--port", "0", "--no-browser"]);
    p.stdout.on("data", (d) => {
      const m = /at (http:\S+)/.exec(String(d));
      if (m) resolve([p, m[1]]);
    });
    p.on("exit", (c) => reject(new Error(`cvt_view.py exited with ${c}`)));
  });
}

const near = (a, b, tol) => Math.abs(a[0] - b[0]) <= tol && Math.abs(a[1] - b[1]) <= tol && Math.abs(a[2] - b[2]) <= tol;
const pixel = (png, x, y) => {
  const i = (png.width * Math.round(y) + Math.round(x)) * 4;
  return [png.data[i], png.data[i + 1], png.data[i + 2]];
};
// Whether a pixel within r of (x, y) is not the background.
const drawnNear = (png, x, y, r = 3) => {
  for (let dy = -r; dy <= r; ++dy)
    for (let dx = -r; dx <= r; ++dx) {
      const X = x + dx, Y = y + dy;
      if (X >= 0 && Y >= 0 && X < png.width && Y < png.height && !near(pixel(png, X, Y), BG, 8)) return true;
    }
  return false;
};

async function shot(name) {
  const buf = await page.locator("#view").screenshot();
  writeFileSync(join(SHOTS, name), buf);
  return PNG.sync.read(buf);
}

// The joints of the straight strands (off both pulleys), projected, with their links' colours.
async function strandJoints() {
  return page.evaluate(() => {
    const { run, view } = window.cvtView, L = run.layout, s = view.frame, N = run.N, out = [];
    const [lo, hi] = run.tensionRange;
    for (let j = 0; j < N; ++j) {
      const x = run.position[(s * N + j) * 3], y = run.position[(s * N + j) * 3 + 1];
      const off = L.pulleys.every((p) => Math.hypot(x - p.centre[0], y - p.centre[1]) > 1.15 * p.running_radius);
      // The pin halves' ends, a little inside each end (the ends are the cylinders' caps).
      const ends = [];
      for (let h = 0; h < 2; ++h) {
        const o = ((s * N + j) * 2 + h) * 6, e = run.ends;
        for (const f of [0.2, 0.8])
          ends.push(view.projectPoint(e[o] + f * (e[o + 3] - e[o]), e[o + 1] + f * (e[o + 4] - e[o + 1]),
                                      e[o + 2] + f * (e[o + 5] - e[o + 2])));
      }
      if (off) out.push({ j, xy: view.project(j), ends, x: (run.tension[s * N + j] - lo) / (hi - lo) });
    }
    return out;
  });
}

before(async () => {
  const file = join(dir, "mini.h5");
  execFileSync(EXE, ["run", join(ROOT, "configs", "mini.toml"), "--t-end", "0.005", "--set",
                     "run.snapshot_interval=2.5e-4", "--out", file, "--quiet"]);
  [server, url] = await startServer(file);
  ({ browser, page } = await openViewer(url, { width: 1000, height: 760 }));
});

after(async () => {
  if (browser) await browser.close();
  if (server) server.kill();
  console.log(`screenshots in ${SHOTS}`);
});

test("draws the chain where the snapshot puts it, in the colours of the tension scale", async () => {
  // The middle snapshot: the chain runs under load, its links in several colours.
  await page.evaluate(() => window.cvtView.show(window.cvtView.frames >> 1));
  let png = await shot("viewer-first.png");
  const joints = await strandJoints();
  assert.ok(joints.length >= 6, `joints on the strands: ${joints.length}`);
  // Between the strands, half way between the shafts, there is nothing.
  const mid = await page.evaluate(() => {
    const { run, view } = window.cvtView, c = run.layout.pulleys.map((p) => p.centre);
    const THREEv = view.camera.position.clone();  // a vector of the right class
    THREEv.set((c[0][0] + c[1][0]) / 2 * 1000, (c[0][1] + c[1][1]) / 2 * 1000, 0).project(view.camera);
    return [(THREEv.x + 1) / 2 * view.renderer.domElement.width, (1 - THREEv.y) / 2 * view.renderer.domElement.height];
  });

  // The plate packs' colours are the colour bar's: each strand link's colour is on the screen
  // (seen without the sheaves, which are drawn translucent over the chain).
  await page.click("#sheaves");
  png = await shot("viewer-first-no-sheaves.png");
  await page.click("#sheaves");
  // Without the translucent sheaves over it, the chain alone: each strand joint and every
  // pin half along the line between its ends.
  for (const { j, xy } of joints) assert.ok(drawnNear(png, xy[0], xy[1]), `joint ${j} at ${xy} not drawn`);
  for (const { j, ends } of joints)
    for (const e of ends) assert.ok(drawnNear(png, e[0], e[1], 2), `pin half of joint ${j} at ${e} not drawn`);
  assert.ok(near(pixel(png, mid[0], mid[1]), BG, 8), `background expected between the strands at ${mid}`);
  let found = 0;
  for (const { x } of joints) {
    const want = colormap(x).map((v) => Math.round(255 * v));
    let hit = false;
    for (let i = 0; i < png.data.length && !hit; i += 4)
      hit = near([png.data[i], png.data[i + 1], png.data[i + 2]], want, 4);
    found += hit;
  }
  assert.ok(found >= 0.8 * joints.length, `${found} of ${joints.length} link colours on the screen`);
  const bar = PNG.sync.read(await page.locator("#colorbar").screenshot());
  for (const end of [0, 1]) {
    const want = colormap(end).map((v) => Math.round(255 * v));
    let hit = false;
    for (let i = 0; i < bar.data.length && !hit; i += 4) hit = near([bar.data[i], bar.data[i + 1], bar.data[i + 2]], want, 6);
    assert.ok(hit, `colour bar end ${end}`);
  }
});

test("the slider moves the chain to the snapshot it names", async () => {
  const before = await strandJoints();
  const first = await page.evaluate(() => window.cvtView.view.frame);
  await page.focus("#slider");
  await page.keyboard.press("End");
  const state = await page.evaluate(() => ({ frame: window.cvtView.view.frame, frames: window.cvtView.frames,
                                             label: document.getElementById("time").textContent }));
  assert.equal(first, await page.evaluate(() => window.cvtView.frames >> 1));
  assert.equal(state.frame, state.frames - 1);
  assert.match(state.label, /t = 5\.000 ms/);
  await shot("viewer-last.png");
  await page.click("#sheaves");
  const png = await shot("viewer-last-no-sheaves.png");
  await page.click("#sheaves");
  const after = await strandJoints();
  for (const { j, xy } of after) assert.ok(drawnNear(png, xy[0], xy[1]), `joint ${j} at ${xy} not drawn`);
  // The chain has moved on the screen: the joints are elsewhere.
  const moved = before.filter(({ j, xy }) => {
    const a = after.find((x) => x.j === j);
    return !a || Math.hypot(a.xy[0] - xy[0], a.xy[1] - xy[1]) > 5;
  });
  assert.ok(moved.length >= 0.8 * before.length, `${moved.length} of ${before.length} joints moved`);
});

test("a recorded video plays", async () => {
  const webm = join(dir, "view.webm");
  execFileSync("/usr/bin/python3", [join(ROOT, "tools", "cvt_view.py"), join(dir, "mini.h5"), "--port", "0",
                                    "--video", webm, "--fps", "20", "--size", "640x360"]);
  const bytes = readFileSync(webm);
  assert.ok(bytes.length > 10000, `${bytes.length} bytes`);
  assert.deepEqual([...bytes.subarray(0, 4)], [0x1a, 0x45, 0xdf, 0xa3]);  // EBML: a WebM file
  const played = await page.evaluate(async (b64) => {
    const v = document.createElement("video");
    v.muted = true;
    v.src = "data:video/webm;base64," + b64;
    await new Promise((ok, fail) => { v.onloadeddata = ok; v.onerror = () => fail(new Error("cannot decode")); });
    // The duration of a WebM without a duration field shows once the end is found.
    v.currentTime = 1e6;
    await new Promise((ok) => (v.onseeked = ok));
    const duration = v.duration;
    v.currentTime = 0;
    await new Promise((ok) => (v.onseeked = ok));
    await v.play();
    await new Promise((ok) => setTimeout(ok, 300));
    const c = document.createElement("canvas");
    c.width = v.videoWidth, c.height = v.videoHeight;
    const g = c.getContext("2d");
    g.drawImage(v, 0, 0);
    const d = g.getImageData(0, 0, c.width, c.height).data;
    let lit = 0;
    for (let i = 0; i < d.length; i += 4) lit += Math.abs(d[i] - 0x1e) + Math.abs(d[i + 1] - 0x22) + Math.abs(d[i + 2] - 0x28) > 40;
    return { w: v.videoWidth, h: v.videoHeight, t: v.currentTime, lit: lit / (d.length / 4), duration };
  }, bytes.toString("base64"));
  assert.equal(played.w, 640);  // the canvas of a 640 x 360 page: its width, its height less the bars
  assert.ok(played.h > 100 && played.h < 360, `height ${played.h}`);
  assert.ok(played.t > 0, `played to ${played.t} s`);
  // One snapshot per frame at 20 frames per second: 21 snapshots last 1.05 s.
  const frames = await page.evaluate(() => window.cvtView.frames);
  assert.ok(Math.abs(played.duration - frames / 20) < 0.1, `duration ${played.duration} s for ${frames} frames`);
  assert.ok(played.lit > 0.01, `drawn part of a frame: ${played.lit}`);
});
