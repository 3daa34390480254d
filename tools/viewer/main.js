// The viewer page (docs/viewer.md): opens the results file named by ?file= (default run.h5,
// what tools/cvt_view.py serves), draws it, and wires the slider, play/pause, the channel
// plot and the video recorder. window.cvtView is the page's handle for scripts (the browser
// test, tools/viewer/record.mjs).
import * as h5wasm from "h5wasm";
import { ArrayBufferTarget, Muxer } from "webm-muxer";
import { colormap, frameAt, readRun } from "./data.js";
import { CvtView } from "./view.js";

const $ = (id) => document.getElementById(id);
const api = (window.cvtView = { ready: false, error: null });

function drawColorbar(range) {
  const c = $("colorbar");
  c.width = 78;
  const g = c.getContext("2d"), h = c.height, top = 6, bottom = h - 6;
  g.clearRect(0, 0, c.width, h);
  for (let y = top; y < bottom; ++y) {
    const [r, gg, b] = colormap(1 - (y - top) / (bottom - top - 1));
    g.fillStyle = `rgb(${Math.round(255 * r)},${Math.round(255 * gg)},${Math.round(255 * b)})`;
    g.fillRect(c.width - 22, y, 22, 1);
  }
  g.fillStyle = "#e4e7eb";
  g.font = "11px sans-serif";
  g.textAlign = "right";
  for (let i = 0; i <= 4; ++i) {
    const y = bottom - (i / 4) * (bottom - top);
    g.fillText((range[0] + (i / 4) * (range[1] - range[0])).toFixed(0), c.width - 26, y + 4);
  }
}

function drawPlot(run, name, t) {
  const c = $("plot");
  c.width = c.clientWidth;
  c.height = c.clientHeight;
  const g = c.getContext("2d"), W = c.width, H = c.height, pad = 42;
  g.clearRect(0, 0, W, H);
  if (!name) return;
  const ch = run.channel(name), n = ch.t.length;
  let lo = Infinity, hi = -Infinity;
  for (let i = 0; i < n; ++i) {
    const v = ch.v[i * ch.stride];
    if (Number.isFinite(v)) lo = Math.min(lo, v), hi = Math.max(hi, v);
  }
  if (!(hi > lo)) hi = lo + 1;
  const t0 = ch.t[0], t1 = ch.t[n - 1] > t0 ? ch.t[n - 1] : t0 + 1;
  const X = (tt) => pad + (tt - t0) / (t1 - t0) * (W - pad - 8), Y = (v) => H - 16 - (v - lo) / (hi - lo) * (H - 26);
  g.strokeStyle = "#556";
  g.strokeRect(pad, 6, W - pad - 8, H - 22);
  g.strokeStyle = "#6cb4ff";
  g.beginPath();
  for (let i = 0; i < n; ++i) g[i ? "lineTo" : "moveTo"](X(ch.t[i]), Y(ch.v[i * ch.stride]));
  g.stroke();
  g.strokeStyle = "#ffb347";
  g.beginPath();
  g.moveTo(X(t), 6);
  g.lineTo(X(t), H - 16);
  g.stroke();
  g.fillStyle = "#c8ccd2";
  g.font = "11px sans-serif";
  g.fillText(hi.toPrecision(4), 2, 14);
  g.fillText(lo.toPrecision(4), 2, H - 18);
  g.fillText(`${name}${ch.stride > 1 ? "[0]" : ""} [${ch.unit}]   t = ${t0.toFixed(4)} .. ${t1.toFixed(4)} s`, pad + 4, H - 3);
}

async function open() {
  const query = new URLSearchParams(location.search), url = query.get("file") || "run.h5";
  $("file").textContent = query.get("name") || url.split("/").pop();
  const response = await fetch(url);
  if (!response.ok) throw new Error(`cannot fetch ${url}: ${response.status}`);
  const bytes = new Uint8Array(await response.arrayBuffer());
  const { FS } = await h5wasm.ready;
  FS.writeFile("run.h5", bytes);
  return readRun(new h5wasm.File("run.h5", "r"));
}

async function main() {
  const run = await open();
  const view = new CvtView($("view"), run);
  const slider = $("slider"), select = $("channel");
  slider.max = String(run.S - 1);
  for (const name of run.channelNames) select.add(new Option(name, name));
  select.value = run.channelNames.includes("output_torque") ? "output_torque" : run.channelNames[0] || "";
  drawColorbar(run.tensionRange);
  $("arrows").textContent = run.normal ? "arrows: pin-sheave normal forces" : "";
  const show = (s) => {
    s = Math.max(0, Math.min(run.S - 1, s | 0));
    slider.value = String(s);
    view.setFrame(s);
    $("time").textContent = `t = ${(run.times[s] * 1e3).toFixed(3)} ms  (${s + 1}/${run.S})`;
    drawPlot(run, select.value, run.times[s]);
  };
  const fit = () => {
    const st = $("stage");
    view.resize(st.clientWidth, st.clientHeight);
    show(view.frame ?? Number(slider.value));
  };
  window.addEventListener("resize", fit);
  slider.addEventListener("input", () => show(Number(slider.value)));
  select.addEventListener("change", () => show(view.frame));
  $("sheaves").addEventListener("change", () => view.showSheaves($("sheaves").checked));
  let timer = null;
  const play = () => {
    if (timer) {
      clearInterval(timer), timer = null, $("play").innerHTML = "&#9654; play";
      return;
    }
    $("play").innerHTML = "&#10074;&#10074; pause";
    timer = setInterval(() => show(view.frame + 1 < run.S ? view.frame + 1 : 0), 33);
  };
  $("play").addEventListener("click", play);
  window.addEventListener("keydown", (e) => { if (e.code === "Space" && e.target === document.body) play(); });
  // The video: every snapshot once, fps frames per second of video, VP8 in WebM, each frame
  // encoded with its own timestamp (WebCodecs), so the video's time does not depend on how
  // fast the page draws.
  const record = async (fps = 30) => {
    const canvas = $("view"), width = canvas.width, height = canvas.height;
    const muxer = new Muxer({ target: new ArrayBufferTarget(), video: { codec: "V_VP8", width, height, frameRate: fps } });
    let failure = null;
    const encoder = new VideoEncoder({ output: (chunk, meta) => muxer.addVideoChunk(chunk, meta),
                                       error: (e) => (failure = e) });
    encoder.configure({ codec: "vp8", width, height, bitrate: 6e6, framerate: fps });
    for (let s = 0; s < run.S && !failure; ++s) {
      show(s);
      const frame = new VideoFrame(canvas, { timestamp: Math.round(s * 1e6 / fps), duration: Math.round(1e6 / fps) });
      encoder.encode(frame, { keyFrame: s % (2 * fps) === 0 });
      frame.close();
      while (encoder.encodeQueueSize > 4) await new Promise((r) => setTimeout(r, 5));
    }
    await encoder.flush();
    if (failure) throw failure;
    muxer.finalize();
    return new Blob([muxer.target.buffer], { type: "video/webm" });
  };
  $("record").addEventListener("click", async () => {
    $("record").disabled = true;
    const blob = await record();
    const a = document.createElement("a");
    a.href = URL.createObjectURL(blob);
    a.download = "cvt-view.webm";
    a.click();
    $("record").disabled = false;
  });
  Object.assign(api, {
    run, view, show, frames: run.S, times: run.times,
    project: (j) => view.project(j),
    frameAt: (t) => frameAt(run.times, t),
    recordBase64: async (fps) => {
      const buf = new Uint8Array(await (await record(fps)).arrayBuffer());
      let s = "";
      for (let i = 0; i < buf.length; i += 0x8000) s += String.fromCharCode(...buf.subarray(i, i + 0x8000));
      return btoa(s);
    },
  });
  fit();
  $("status").textContent = "";
  api.ready = true;
}

main().catch((e) => {
  api.error = String(e && e.message ? e.message : e);
  $("status").textContent = api.error;
  console.error(e);
});
