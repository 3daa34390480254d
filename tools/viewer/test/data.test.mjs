// The data loading of the viewer (data.js) on a file written here with h5wasm, in the
// layout of docs/output.md: snapshots, layout, channels, interpolation, the colour range and
// the errors for files it cannot show.
import { test } from "node:test";
import assert from "node:assert/strict";
import { mkdtempSync } from "node:fs";
import { tmpdir } from "node:os";
import { join } from "node:path";
import h5wasm from "h5wasm/node";
import { colormap, frameAt, interpolate, readRun, tensionRange } from "../data.js";

await h5wasm.ready;
const dir = mkdtempSync(join(tmpdir(), "cvt-viewer-"));
const LAYOUT = { links: 3, tracked_pin: 0, cone_angle: 0.19, hub_radius: 0.01, outer_radius: 0.035,
                 pin_length: 0.036, plate_spread: 0.024, pitch: 0.008,
                 pulleys: [{ centre: [0, 0], face_z: [-0.004, 0.004], moving_side: 1, running_radius: 0.019 },
                           { centre: [0.06, 0], face_z: [-0.004, 0.004], moving_side: -1, running_radius: 0.019 }] };

function write(name, { snapshots = true, layout = true } = {}) {
  const path = join(dir, name);
  const f = new h5wasm.File(path, "w");
  f.create_group("parameters");
  if (layout) f.get("parameters").create_attribute("layout", JSON.stringify(LAYOUT));
  for (const g of ["observables", "observables/sheave_position", "observables/output_torque"]) f.create_group(g);
  const T = [0, 1e-3, 2e-3];
  f.get("observables/sheave_position").create_dataset({ name: "time", data: new Float64Array(T) });
  f.get("observables/sheave_position").create_dataset({ name: "value", data: new Float64Array([0, 0, 1e-4, -2e-4, 3e-4, -4e-4]), shape: [3, 2] });
  f.get("observables/output_torque").create_dataset({ name: "time", data: new Float64Array(T) });
  f.get("observables/output_torque").create_dataset({ name: "value", data: new Float64Array([0, 5, 10]) });
  f.get("observables/output_torque/value").create_attribute("unit", "N m");
  if (snapshots) {
    for (const g of ["particles", "particles/chain", "particles/chain/position", "particles/chain/link_tension",
                     "particles/chain/pin_end_position", "particles/chain/pin_end_normal_force"]) f.create_group(g);
    const S = 2, N = 3, ts = new Float64Array([0, 1.5e-3]);
    const put = (g, data, shape) => {
      f.get(g).create_dataset({ name: "time", data: ts });
      f.get(g).create_dataset({ name: "value", data: new Float64Array(data), shape });
    };
    put("particles/chain/position", Array.from({ length: S * N * 3 }, (_, i) => i * 1e-3), [S, N, 3]);
    put("particles/chain/link_tension", [100, 200, 300, 400, 500, 600], [S, N]);
    put("particles/chain/pin_end_position", Array.from({ length: S * N * 12 }, (_, i) => i * 1e-4), [S, N, 2, 2, 3]);
    put("particles/chain/pin_end_normal_force", Array.from({ length: S * N * 4 }, (_, i) => i % 3), [S, N, 2, 2]);
  }
  f.close();
  return new h5wasm.File(path, "r");
}

test("reads the snapshots, the layout and the channels", () => {
  const run = readRun(write("full.h5"));
  assert.equal(run.N, 3);
  assert.equal(run.S, 2);
  assert.deepEqual(Array.from(run.times), [0, 1.5e-3]);
  assert.deepEqual(run.layout.pulleys[1].centre, [0.06, 0]);
  assert.equal(run.position.length, 18);
  assert.equal(run.position[3 * 3 + 1], 10e-3);  // snapshot 1, joint 0, y
  assert.equal(run.ends.length, 72);
  assert.equal(run.normal.length, 24);
  // The moving sheaves at the snapshot times, interpolated in the channel: 1.5 ms is half way.
  assert.ok(Math.abs(run.sheave[2] - 2e-4) < 1e-15 && Math.abs(run.sheave[3] + 3e-4) < 1e-15);
  assert.deepEqual(run.channelNames, ["output_torque", "sheave_position"]);
  const c = run.channel("output_torque");
  assert.equal(c.unit, "N m");
  assert.equal(c.stride, 1);
  assert.equal(run.channel("sheave_position").stride, 2);
  assert.throws(() => run.channel("nothing"), /no channel 'nothing'/);
  assert.deepEqual(run.tensionRange, [100, 600]);
});

test("says what is missing", () => {
  assert.throws(() => readRun(write("nosnap.h5", { snapshots: false })), /run.snapshot_interval > 0/);
  assert.throws(() => readRun(write("nolayout.h5", { layout: false })), /no 'layout' attribute/);
});

test("interpolates, finds the frame and maps colours", () => {
  const tt = new Float64Array([0, 1, 3]), vv = new Float64Array([0, 10, 1, 20, 3, 40]);
  assert.equal(interpolate(tt, vv, 2, 0, 2), 2);
  assert.equal(interpolate(tt, vv, 2, 1, 0.5), 15);
  assert.equal(interpolate(tt, vv, 2, 1, -1), 10);
  assert.equal(interpolate(tt, vv, 2, 1, 9), 40);
  assert.equal(frameAt(tt, 0.99), 0);
  assert.equal(frameAt(tt, 1), 1);
  assert.equal(frameAt(tt, 7), 2);
  assert.deepEqual(colormap(0), [0.267, 0.005, 0.329]);
  assert.deepEqual(colormap(1), [0.993, 0.906, 0.144]);
  assert.deepEqual(colormap(2), colormap(1));
  const mid = colormap(0.5);
  assert.ok(mid[1] > colormap(0)[1] && mid[1] < colormap(1)[1]);
  // A start-up spike in one link of one snapshot does not set the top of the scale.
  const t = Array.from({ length: 1000 }, (_, i) => 100 + (i % 50));
  t[7] = 1e5;
  assert.deepEqual(tensionRange(t), [100, 149]);
});
