// A small 3D renderer on canvas 2D: an orbit camera, a perspective projection of our own, a ground grid,
// skeletons drawn as depth-sorted bones with shadows, and markers on the ground. Canvas 2D rather than
// WebGL: a few hundred lines a frame is nothing for it, and it draws the same in headless Chromium
// without a GPU, which is how the tests see it. World: Y up, centimetres (the model's units).

import { add, cross, dot, normalize, scale, sub } from "./math.js";

const NEAR = 5; // cm in front of the eye; geometry closer is clipped, never projected through the eye

export class OrbitCamera {
  constructor() {
    this.center = [0, 90, 0]; // what the camera looks at and orbits around
    this.yaw = Math.PI * 0.78;  // radians about +Y
    this.pitch = 0.32;          // radians above the horizon
    this.distance = 560;        // cm
    this.fov = (45 * Math.PI) / 180;
  }

  basis() {
    const cp = Math.cos(this.pitch);
    const eye = add(this.center, scale([cp * Math.sin(this.yaw), Math.sin(this.pitch), cp * Math.cos(this.yaw)], this.distance));
    const forward = normalize(sub(this.center, eye));
    const right = normalize(cross(forward, [0, 1, 0]));
    const up = cross(right, forward);
    return { eye, forward, right, up };
  }

  orbit(dx, dy) {
    this.yaw -= dx * 0.008;
    this.pitch = Math.min(1.45, Math.max(0.03, this.pitch + dy * 0.006));
  }

  // Ease the centre towards a point on the ground (x, z of p): the character stays in view without
  // the camera jerking with every step.
  follow(p, k = 0.08) {
    this.center = [this.center[0] + (p[0] - this.center[0]) * k, this.center[1], this.center[2] + (p[2] - this.center[2]) * k];
  }

  zoom(factor) { this.distance = Math.min(6000, Math.max(80, this.distance * factor)); }

  pan(dx, dy) {
    // Move the centre in the ground plane, scaled so the ground under the cursor roughly follows it.
    const { right, forward } = this.basis();
    const k = this.distance * 0.0015;
    const flat = normalize([forward[0], 0, forward[2]]);
    this.center = add(this.center, add(scale(right, -dx * k), scale(flat, dy * k)));
  }
}

export class Renderer {
  constructor(canvas, camera) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.camera = camera;
    this.resize();
  }

  resize() {
    // Draw at device pixels for sharp lines; everything else works in CSS pixels.
    const dpr = window.devicePixelRatio || 1;
    const r = this.canvas.getBoundingClientRect();
    this.width = Math.max(1, r.width);
    this.height = Math.max(1, r.height);
    this.canvas.width = Math.round(this.width * dpr);
    this.canvas.height = Math.round(this.height * dpr);
    this.ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  }

  frame() {
    const b = this.camera.basis();
    b.focal = this.height / 2 / Math.tan(this.camera.fov / 2);
    return b;
  }

  toView(v, p) {
    const d = sub(p, v.eye);
    return [dot(d, v.right), dot(d, v.up), dot(d, v.forward)];
  }

  fromView(v, c) { return [v.focal * (c[0] / c[2]) + this.width / 2, this.height / 2 - v.focal * (c[1] / c[2]), c[2]]; }

  // Screen position [x, y, depth] in CSS pixels, or null behind the near plane.
  project(p, v = this.frame()) {
    const c = this.toView(v, p);
    return c[2] < NEAR ? null : this.fromView(v, c);
  }

  // A segment clipped to the near plane, projected; null when wholly behind the eye.
  segment(v, a, b) {
    let ca = this.toView(v, a), cb = this.toView(v, b);
    if (ca[2] < NEAR && cb[2] < NEAR) return null;
    if (ca[2] < NEAR || cb[2] < NEAR) {
      const t = (NEAR - ca[2]) / (cb[2] - ca[2]);
      const m = [ca[0] + (cb[0] - ca[0]) * t, ca[1] + (cb[1] - ca[1]) * t, NEAR];
      if (ca[2] < NEAR) ca = m; else cb = m;
    }
    return [this.fromView(v, ca), this.fromView(v, cb)];
  }

  // The point on the ground (y = 0) under a CSS pixel, or null when the ray misses it.
  pickGround(x, y) {
    const v = this.frame();
    const dir = add(v.forward, add(scale(v.right, (x - this.width / 2) / v.focal), scale(v.up, (this.height / 2 - y) / v.focal)));
    if (dir[1] > -1e-6) return null;
    const t = -v.eye[1] / dir[1];
    return t > 0 ? add(v.eye, scale(dir, t)) : null;
  }

  // scene: {skeletons: [{positions, parents, color, label, alpha, width}], markers: [{point, yaw, color, label}],
  //         trails: [{points: [[x,y,z]], color}]}
  draw(scene) {
    const ctx = this.ctx, v = this.frame();
    ctx.fillStyle = "#15181d";
    ctx.fillRect(0, 0, this.width, this.height);
    this.drawGrid(v);
    for (const t of scene.trails || []) this.drawTrail(v, t);
    for (const m of scene.markers || []) this.drawMarker(v, m);
    this.drawSkeletons(v, scene.skeletons || []);
  }

  drawGrid(v) {
    // A square of lines around the ground point below the orbit centre, snapped to the spacing so the
    // lines stay put while the camera follows a character. Lines are 50 cm apart, every metre brighter.
    const ctx = this.ctx;
    const step = 50, n = Math.ceil(Math.min(4000, this.camera.distance * 2.5) / step);
    const cx = Math.round(this.camera.center[0] / step) * step, cz = Math.round(this.camera.center[2] / step) * step;
    const ext = n * step;
    for (let i = -n; i <= n; i++) {
      const major = Math.round((cx + i * step) / step) % 2 === 0;
      ctx.strokeStyle = major ? "rgba(170,180,195,0.30)" : "rgba(170,180,195,0.12)";
      ctx.lineWidth = 1;
      this.line(v, [cx + i * step, 0, cz - ext], [cx + i * step, 0, cz + ext]);
      const majorZ = Math.round((cz + i * step) / step) % 2 === 0;
      ctx.strokeStyle = majorZ ? "rgba(170,180,195,0.30)" : "rgba(170,180,195,0.12)";
      this.line(v, [cx - ext, 0, cz + i * step], [cx + ext, 0, cz + i * step]);
    }
    // The world axes through the origin: X red, Z blue (Y is up, out of the grid).
    ctx.lineWidth = 2;
    ctx.strokeStyle = "rgba(230,90,90,0.7)"; this.line(v, [0, 0.1, 0], [100, 0.1, 0]);
    ctx.strokeStyle = "rgba(90,140,230,0.7)"; this.line(v, [0, 0.1, 0], [0, 0.1, 100]);
  }

  line(v, a, b) {
    const s = this.segment(v, a, b);
    if (!s) return;
    this.ctx.beginPath(); this.ctx.moveTo(s[0][0], s[0][1]); this.ctx.lineTo(s[1][0], s[1][1]); this.ctx.stroke();
  }

  drawTrail(v, trail) {
    const ctx = this.ctx;
    ctx.strokeStyle = trail.color; ctx.lineWidth = 1.5; ctx.globalAlpha = 0.55;
    for (let i = 1; i < trail.points.length; i++) this.line(v, trail.points[i - 1], trail.points[i]);
    ctx.globalAlpha = 1;
  }

  drawMarker(v, m) {
    // A ring on the ground and an arrow for the facing (yaw 0 = +Z).
    const ctx = this.ctx, r = 25;
    ctx.strokeStyle = m.color; ctx.lineWidth = 2.5;
    const pts = [];
    for (let i = 0; i <= 24; i++) {
      const a = (i / 24) * Math.PI * 2;
      pts.push([m.point[0] + r * Math.cos(a), 0.5, m.point[2] + r * Math.sin(a)]);
    }
    for (let i = 1; i < pts.length; i++) this.line(v, pts[i - 1], pts[i]);
    if (m.yaw !== undefined && m.yaw !== null) {
      const f = [Math.sin(m.yaw), 0, Math.cos(m.yaw)], s = [f[2], 0, -f[0]];
      const tip = add(m.point, scale(f, 60));
      this.line(v, add(m.point, [0, 0.5, 0]), add(tip, [0, 0.5, 0]));
      this.line(v, tip, add(tip, add(scale(f, -18), scale(s, 10))));
      this.line(v, tip, add(tip, add(scale(f, -18), scale(s, -10))));
    }
    if (m.label) this.label(v, add(m.point, [0, 8, 0]), m.label, m.color);
  }

  drawSkeletons(v, skeletons) {
    // Shadows first (flattened on the ground), then every bone of every skeleton sorted far to near,
    // so overlapping characters occlude each other correctly enough for stick figures.
    const ctx = this.ctx, bones = [];
    ctx.lineCap = "round";
    for (const s of skeletons) {
      const P = (j) => [s.positions[j * 3], s.positions[j * 3 + 1], s.positions[j * 3 + 2]];
      const shadow = (s.alpha ?? 1) === 1; // ghosts (faint poses) cast none: less clutter on the ground
      ctx.strokeStyle = "rgba(0,0,0,0.35)"; ctx.lineWidth = 3;
      for (let j = 0; j < s.parents.length; j++) {
        const p = s.parents[j];
        if (p < 0) continue;
        const a = P(p), b = P(j);
        if (shadow) this.line(v, [a[0], 0.2, a[2]], [b[0], 0.2, b[2]]);
        const seg = this.segment(v, a, b);
        if (seg) bones.push({ seg, depth: (seg[0][2] + seg[1][2]) / 2, s, j });
      }
    }
    bones.sort((x, y) => y.depth - x.depth);
    for (const b of bones) {
      const w = Math.max(1.5, ((b.s.width || 4.5) * v.focal) / b.depth);
      ctx.globalAlpha = b.s.alpha ?? 1;
      ctx.strokeStyle = b.s.side && b.s.side[b.j] < 0 ? shade(b.s.color, 0.72) : b.s.color;
      ctx.lineWidth = w;
      ctx.beginPath(); ctx.moveTo(b.seg[0][0], b.seg[0][1]); ctx.lineTo(b.seg[1][0], b.seg[1][1]); ctx.stroke();
    }
    ctx.globalAlpha = 1;
    for (const s of skeletons) {
      if (!s.label) continue;
      let top = 0;
      for (let j = 1; j < s.parents.length; j++) if (s.positions[j * 3 + 1] > s.positions[top * 3 + 1]) top = j;
      this.label(v, [s.positions[top * 3], s.positions[top * 3 + 1] + 22, s.positions[top * 3 + 2]], s.label, s.color);
    }
  }

  label(v, p, text, color) {
    const q = this.project(p, v);
    if (!q) return;
    const ctx = this.ctx;
    ctx.font = "600 12px system-ui, sans-serif";
    ctx.textAlign = "center";
    ctx.fillStyle = "rgba(10,12,16,0.75)";
    const w = ctx.measureText(text).width + 10;
    ctx.fillRect(q[0] - w / 2, q[1] - 15, w, 18);
    ctx.fillStyle = color;
    ctx.fillText(text, q[0], q[1] - 2);
  }
}

// A darker tint of a #rrggbb colour, for the left side of a skeleton (so its handedness reads at a glance).
function shade(hex, k) {
  const n = parseInt(hex.slice(1), 16);
  const c = (s) => Math.round(((n >> s) & 255) * k);
  return `rgb(${c(16)},${c(8)},${c(0)})`;
}
