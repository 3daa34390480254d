// The data of a cvt-engine results file for the 3D view (docs/viewer.md): the snapshots of
// /particles/chain, the layout of /parameters, the channels of /observables. Plain arrays
// only, nothing of three.js, so that it runs in Node as well as in the browser.

// The viridis colour map, 9 stops, linear in between: x in [0, 1] -> [r, g, b] in [0, 1].
const VIRIDIS = [
  [0.267, 0.005, 0.329], [0.279, 0.175, 0.483], [0.230, 0.322, 0.546], [0.173, 0.449, 0.558],
  [0.128, 0.567, 0.551], [0.154, 0.680, 0.504], [0.363, 0.784, 0.388], [0.678, 0.864, 0.190],
  [0.993, 0.906, 0.144],
];

export function colormap(x) {
  const u = Math.min(1, Math.max(0, Number.isFinite(x) ? x : 0)) * (VIRIDIS.length - 1);
  const i = Math.min(VIRIDIS.length - 2, Math.floor(u));
  const f = u - i;
  return VIRIDIS[i].map((a, c) => a + f * (VIRIDIS[i + 1][c] - a));
}

// Linear interpolation of column col of a [T][stride] series (times tt, ascending) at t,
// held constant outside the times.
export function interpolate(tt, vv, stride, col, t) {
  const n = tt.length;
  if (n === 0) return NaN;
  if (t <= tt[0]) return vv[col];
  if (t >= tt[n - 1]) return vv[(n - 1) * stride + col];
  let lo = 0, hi = n - 1;
  while (hi - lo > 1) {
    const mid = (lo + hi) >> 1;
    if (tt[mid] <= t) lo = mid; else hi = mid;
  }
  const f = (t - tt[lo]) / (tt[hi] - tt[lo]);
  return vv[lo * stride + col] + f * (vv[hi * stride + col] - vv[lo * stride + col]);
}

// The colour bar's range of the link tensions [N]: from the smallest tension to the 99th
// percentile of all links in all snapshots (a start-up spike does not wash out the rest).
export function tensionRange(tension) {
  if (tension.length === 0) return [0, 1];
  const sorted = Float64Array.from(tension).sort();
  const lo = sorted[0];
  let hi = sorted[Math.min(sorted.length - 1, Math.floor(0.99 * sorted.length))];
  if (!(hi > lo)) hi = lo + 1;
  return [lo, hi];
}

function dataset(file, path) {
  const d = file.get(path);
  return d ? d.value : null;
}

function attribute(obj, name) {
  const a = obj && obj.attrs ? obj.attrs[name] : undefined;
  return a === undefined ? undefined : a.value;
}

// Everything the view needs from an open h5wasm File. Throws an Error that says what is
// missing when the file has no snapshots or is not a cvt-engine results file.
export function readRun(file) {
  const params = file.get("parameters");
  const layoutText = attribute(params, "layout");
  if (layoutText === undefined)
    throw new Error("not a cvt-engine results file with a layout (/parameters has no 'layout' attribute)");
  const layout = JSON.parse(layoutText);
  const N = layout.links;
  const times = dataset(file, "particles/chain/position/time");
  if (!times || times.length === 0)
    throw new Error("the file has no snapshots of the chain: run with run.snapshot_interval > 0 " +
                    "(e.g. --set run.snapshot_interval=1e-4)");
  const S = times.length;
  const position = dataset(file, "particles/chain/position/value");
  const tension = dataset(file, "particles/chain/link_tension/value");
  const ends = dataset(file, "particles/chain/pin_end_position/value");
  const normal = dataset(file, "particles/chain/pin_end_normal_force/value");
  if (position.length !== S * N * 3 || tension.length !== S * N)
    throw new Error(`snapshot sizes do not match ${N} links and ${S} snapshots`);
  const obs = file.get("observables");
  const channelNames = obs ? obs.keys().sort() : [];
  const channelTime = obs ? dataset(file, `observables/${channelNames[0]}/time`) : new Float64Array();
  const cache = new Map();
  const channel = (name) => {
    if (!cache.has(name)) {
      const d = file.get(`observables/${name}/value`);
      if (!d) throw new Error(`no channel '${name}'`);
      const shape = d.shape;
      cache.set(name, { t: channelTime, v: d.value, stride: shape.length > 1 ? shape[1] : 1,
                        unit: attribute(d, "unit") ?? "" });
    }
    return cache.get(name);
  };
  // The moving sheaves' positions w [m] at the snapshot times (0 without the channel).
  const sheave = new Float64Array(2 * S);
  if (channelNames.includes("sheave_position")) {
    const c = channel("sheave_position");
    for (let s = 0; s < S; ++s)
      for (let k = 0; k < 2; ++k) sheave[2 * s + k] = interpolate(c.t, c.v, 2, k, times[s]);
  }
  return {
    layout, N, S, times, position, tension, sheave, channelNames, channel,
    ends: ends && ends.length === S * N * 12 ? ends : null,
    normal: normal && normal.length === S * N * 4 ? normal : null,
    tensionRange: tensionRange(tension),
  };
}

// The snapshot shown at model time t: the last one at or before it.
export function frameAt(times, t) {
  let lo = 0, hi = times.length - 1;
  if (t >= times[hi]) return hi;
  while (hi - lo > 1) {
    const mid = (lo + hi) >> 1;
    if (times[mid] <= t) lo = mid; else hi = mid;
  }
  return lo;
}
