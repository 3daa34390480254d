// The 3D scene of a run (docs/viewer.md) with three.js: pin halves as cylinders between
// their end nodes, plate packs as boxes between the joint centres coloured by the link's
// tension, sheaves as cones at their running positions, shafts, and pin-sheave normal
// forces as arrows. Lengths in the scene are millimetres; the model's axes are kept
// (chain in the xy plane, shaft axes along z).
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { colormap } from "./data.js";

const MM = 1000;
// Colours as written, to the screen as written: the plate packs show the colour bar's
// colours exactly (the browser test finds them there).
THREE.ColorManagement.enabled = false;
export const BACKGROUND = 0x1e2228;

function sheaveGeometry(layout, side) {
  // The face z = side r tan(beta) relative to its offset on the axis (docs/model.md 4.5.3:
  // l_z = Z + w + sigma r tan(beta)), from the hub to the outer radius, then a back face
  // 15 % of the outer radius behind the face's outer edge.
  const tb = Math.tan(layout.cone_angle);
  const r0 = layout.hub_radius * MM, r1 = layout.outer_radius * MM;
  const zHub = side * r0 * tb, zOuter = side * r1 * tb, back = zOuter + side * 0.15 * r1;
  const pts = [[r0 * 0.6, zHub], [r0, zHub], [r1, zOuter], [r1, back], [r0 * 0.6, back]].map(
    ([r, z]) => new THREE.Vector2(r, z));
  const g = new THREE.LatheGeometry(pts, 96);
  g.rotateX(Math.PI / 2);  // the lathe's axis y onto the shaft axis z: profile (r, z) -> scene z
  return g;
}

export class CvtView {
  constructor(canvas, run) {
    this.run = run;
    const L = run.layout;
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(1);
    this.renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(BACKGROUND);
    const c0 = L.pulleys[0].centre, c1 = L.pulleys[1].centre;
    const span = Math.hypot(c1[0] - c0[0], c1[1] - c0[1]) * MM + 2 * L.outer_radius * MM;
    this.centre = new THREE.Vector3((c0[0] + c1[0]) / 2 * MM, (c0[1] + c1[1]) / 2 * MM, 0);
    this.camera = new THREE.PerspectiveCamera(35, 1, span / 100, span * 20);
    this.camera.position.set(this.centre.x, this.centre.y - 0.45 * span, 1.3 * span);
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.target.copy(this.centre);
    this.controls.update();
    this.controls.addEventListener("change", () => this.render());
    this.scene.add(new THREE.AmbientLight(0xffffff, 1.2));
    const sun = new THREE.DirectionalLight(0xffffff, 2.0);
    sun.position.set(1, -1, 2);
    this.scene.add(sun);
    this.buildPulleys();
    this.buildChain();
    this.buildArrows();
  }

  buildPulleys() {
    const L = this.run.layout;
    const mat = new THREE.MeshStandardMaterial({ color: 0x9aa4b1, metalness: 0.3, roughness: 0.5,
                                                 transparent: true, opacity: 0.28, side: THREE.DoubleSide,
                                                 depthWrite: false });
    const shaftMat = new THREE.MeshStandardMaterial({ color: 0x8a939e, metalness: 0.2, roughness: 0.5 });
    const depth = 0.5 * L.pin_length * MM;
    this.moving = [];
    this.sheaves = [];
    L.pulleys.forEach((p, k) => {
      for (const side of [-1, 1]) {
        const zFace = p.face_z[side < 0 ? 0 : 1] * MM;
        const mesh = new THREE.Mesh(sheaveGeometry(L, side), mat);
        mesh.position.set(p.centre[0] * MM, p.centre[1] * MM, zFace);
        mesh.userData.z0 = zFace;
        this.scene.add(mesh);
        this.sheaves.push(mesh);
        if (side === p.moving_side) this.moving[k] = mesh;
      }
      const shaft = new THREE.Mesh(new THREE.CylinderGeometry(0.55 * L.hub_radius * MM, 0.55 * L.hub_radius * MM,
                                                              2.5 * depth, 32), shaftMat);
      shaft.rotation.x = Math.PI / 2;
      shaft.position.set(p.centre[0] * MM, p.centre[1] * MM, 0);
      this.scene.add(shaft);
    });
  }

  buildChain() {
    const L = this.run.layout, N = this.run.N;
    const pinR = 0.09 * L.pitch * MM;
    this.pins = new THREE.InstancedMesh(new THREE.CylinderGeometry(pinR, pinR, 1, 12),
                                        new THREE.MeshStandardMaterial({ color: 0xd8dde3, metalness: 0.6,
                                                                         roughness: 0.35 }), 2 * N);
    // Plate packs unlit, so that their colour on the screen is the colour bar's.
    this.plates = new THREE.InstancedMesh(new THREE.BoxGeometry(1, 1, 1), new THREE.MeshBasicMaterial(), N);
    this.plates.instanceColor = new THREE.InstancedBufferAttribute(new Float32Array(3 * N), 3);
    this.scene.add(this.pins, this.plates);
    this.plateHeight = 0.45 * L.pitch * MM;
    this.plateDepth = L.plate_spread * MM;
  }

  // The arrows: one instanced shaft and one instanced head per pin end (4 N each), so that
  // the whole field costs two draw calls.
  buildArrows() {
    this.arrowShafts = this.arrowHeads = null;
    if (!this.run.normal || !this.run.ends) return;
    let fmax = 0;
    for (const f of this.run.normal) fmax = Math.max(fmax, f);
    this.forceScale = fmax > 0 ? 2.5 * this.run.layout.pitch * MM / fmax : 0;  // mm per N
    const mat = new THREE.MeshBasicMaterial({ color: 0xff5533 });
    const shaft = new THREE.CylinderGeometry(1, 1, 1, 6).translate(0, 0.5, 0);  // base at the origin, along y
    const head = new THREE.ConeGeometry(1, 1, 8).translate(0, 0.5, 0);
    this.arrowShafts = new THREE.InstancedMesh(shaft, mat, 4 * this.run.N);
    this.arrowHeads = new THREE.InstancedMesh(head, mat, 4 * this.run.N);
    this.scene.add(this.arrowShafts, this.arrowHeads);
  }

  // Shows snapshot s.
  setFrame(s) {
    const r = this.run, L = r.layout, N = r.N;
    this.frame = s;
    for (let k = 0; k < 2; ++k) {
      const m = this.moving[k];
      m.position.z = m.userData.z0 + r.sheave[2 * s + k] * MM;
    }
    const P = (j, c) => r.position[(s * N + j) * 3 + c] * MM;
    const mtx = new THREE.Matrix4(), q = new THREE.Quaternion(), up = new THREE.Vector3(0, 1, 0);
    const a = new THREE.Vector3(), b = new THREE.Vector3(), d = new THREE.Vector3(), mid = new THREE.Vector3();
    // Pin halves between their end nodes (or, without them, along z through the joint).
    for (let j = 0; j < N; ++j)
      for (let h = 0; h < 2; ++h) {
        if (r.ends) {
          const o = ((s * N + j) * 2 + h) * 6;
          a.set(r.ends[o] * MM, r.ends[o + 1] * MM, r.ends[o + 2] * MM);
          b.set(r.ends[o + 3] * MM, r.ends[o + 4] * MM, r.ends[o + 5] * MM);
        } else {
          a.set(P(j, 0), P(j, 1), -0.5 * L.pin_length * MM);
          b.set(P(j, 0), P(j, 1), 0.5 * L.pin_length * MM);
        }
        d.subVectors(b, a);
        mid.addVectors(a, b).multiplyScalar(0.5);
        q.setFromUnitVectors(up, d.clone().normalize());
        mtx.compose(mid, q, new THREE.Vector3(1, d.length(), 1));
        this.pins.setMatrixAt(2 * j + h, mtx);
      }
    this.pins.instanceMatrix.needsUpdate = true;
    // Link i joins joints i and i + 1.
    const [lo, hi] = r.tensionRange;
    // A plate pack's box: x along the link, z along the shaft axes, y across.
    const ex = new THREE.Vector3(), ey = new THREE.Vector3(), ez = new THREE.Vector3(0, 0, 1);
    const basis = new THREE.Matrix4();
    for (let i = 0; i < N; ++i) {
      const k = (i + 1) % N;
      a.set(P(i, 0), P(i, 1), P(i, 2));
      b.set(P(k, 0), P(k, 1), P(k, 2));
      d.subVectors(b, a);
      mid.addVectors(a, b).multiplyScalar(0.5);
      ex.copy(d).setZ(0).normalize();
      ey.crossVectors(ez, ex);
      q.setFromRotationMatrix(basis.makeBasis(ex, ey, ez));
      mtx.compose(mid, q, new THREE.Vector3(0.92 * d.length(), this.plateHeight, this.plateDepth));
      this.plates.setMatrixAt(i, mtx);
      const c = colormap((r.tension[s * N + i] - lo) / (hi - lo));
      this.plates.instanceColor.setXYZ(i, c[0], c[1], c[2]);
    }
    this.plates.instanceMatrix.needsUpdate = true;
    this.plates.instanceColor.needsUpdate = true;
    this.plates.computeBoundingSphere();
    this.pins.computeBoundingSphere();
    this.updateArrows(s);
    this.render();
  }

  // Each pin end's normal force on the pin: along the face normal, outward and away from
  // the face (docs/model.md 4.5.3), from the end node, length proportional to the force.
  updateArrows(s) {
    if (!this.arrowShafts) return;
    const r = this.run, L = r.layout, N = r.N, sb = Math.sin(L.cone_angle), cb = Math.cos(L.cone_angle);
    const dir = new THREE.Vector3(), at = new THREE.Vector3(), tip = new THREE.Vector3();
    const q = new THREE.Quaternion(), up = new THREE.Vector3(0, 1, 0), m = new THREE.Matrix4();
    const none = new THREE.Matrix4().makeScale(0, 0, 0);
    const width = 0.04 * L.pitch * MM;
    for (let j = 0; j < N; ++j)
      for (let h = 0; h < 2; ++h)
        for (let e = 0; e < 2; ++e) {
          const i = (j * 2 + h) * 2 + e, f = r.normal[s * N * 4 + i];
          if (!(f > 0)) {
            this.arrowShafts.setMatrixAt(i, none);
            this.arrowHeads.setMatrixAt(i, none);
            continue;
          }
          const o = (s * N + j) * 12 + h * 6 + e * 3;
          at.set(r.ends[o] * MM, r.ends[o + 1] * MM, r.ends[o + 2] * MM);
          const p = L.pulleys.reduce((best, c) => Math.hypot(at.x - c.centre[0] * MM, at.y - c.centre[1] * MM) <
            Math.hypot(at.x - best.centre[0] * MM, at.y - best.centre[1] * MM) ? c : best);
          const lx = at.x - p.centre[0] * MM, ly = at.y - p.centre[1] * MM, rr = Math.hypot(lx, ly);
          const sigma = e === 0 ? -1 : 1;
          dir.set(sb * lx / rr, sb * ly / rr, -sigma * cb).normalize();
          q.setFromUnitVectors(up, dir);
          const len = Math.max(1e-3, f * this.forceScale), headLen = 0.3 * len;
          this.arrowShafts.setMatrixAt(i, m.compose(at, q, new THREE.Vector3(width, len - headLen, width)));
          tip.copy(dir).multiplyScalar(len - headLen).add(at);
          this.arrowHeads.setMatrixAt(i, m.compose(tip, q, new THREE.Vector3(3 * width, headLen, 3 * width)));
        }
    this.arrowShafts.instanceMatrix.needsUpdate = true;
    this.arrowHeads.instanceMatrix.needsUpdate = true;
    this.arrowShafts.computeBoundingSphere();
    this.arrowHeads.computeBoundingSphere();
  }

  showSheaves(on) {
    for (const m of this.sheaves) m.visible = on;
    this.render();
  }

  resize(w, h) {
    w -= w % 2, h -= h % 2;  // even sizes, as video encoders want them
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.render();
  }

  render() {
    this.renderer.render(this.scene, this.camera);
  }

  // Where the model's point (x, y, z) [m] falls on the canvas [px from top left].
  projectPoint(x, y, z) {
    const v = new THREE.Vector3(x * MM, y * MM, z * MM).project(this.camera);
    const c = this.renderer.domElement;
    return [(v.x + 1) / 2 * c.width, (1 - v.y) / 2 * c.height];
  }

  // Where joint j's centre of the current snapshot falls on the canvas.
  project(j) {
    const r = this.run, o = (this.frame * r.N + j) * 3;
    return this.projectPoint(r.position[o], r.position[o + 1], r.position[o + 2]);
  }
}
