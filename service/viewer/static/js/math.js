// Vectors, quaternions (x, y, z, w, as on the wire), forward kinematics and the pose edits the viewer
// needs: the interpolation baseline and moving a pose to a point on the ground with a new facing.
// Plain arrays and Float32Arrays, no classes: everything here is pure and cheap to test by hand.

export const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
export const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
export const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
export const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
export const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
export const length = (a) => Math.hypot(a[0], a[1], a[2]);
export const normalize = (a) => { const n = length(a) || 1; return [a[0] / n, a[1] / n, a[2] / n]; };
export const lerp = (a, b, t) => [a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t, a[2] + (b[2] - a[2]) * t];

export function qmul(a, b) {
  const [ax, ay, az, aw] = a, [bx, by, bz, bw] = b;
  return [aw * bx + ax * bw + ay * bz - az * by,
          aw * by - ax * bz + ay * bw + az * bx,
          aw * bz + ax * by - ay * bx + az * bw,
          aw * bw - ax * bx - ay * by - az * bz];
}

export function qrot(q, v) {
  // v + 2 w (u x v) + 2 u x (u x v), with u the vector part: no matrix needed.
  const u = [q[0], q[1], q[2]], w = q[3];
  const t = scale(cross(u, v), 2);
  return add(add(v, scale(t, w)), cross(u, t));
}

export const yawQuat = (yaw) => [0, Math.sin(yaw / 2), 0, Math.cos(yaw / 2)];

export function qslerp(a, b, t) {
  let d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3];
  // The shorter arc: q and -q are the same rotation.
  const s = d < 0 ? -1 : 1;
  d = Math.abs(d);
  let wa, wb;
  if (d > 0.9995) { wa = 1 - t; wb = t; } // nearly equal: lerp is exact enough and avoids 0/0
  else {
    const th = Math.acos(d), sn = Math.sin(th);
    wa = Math.sin((1 - t) * th) / sn; wb = Math.sin(t * th) / sn;
  }
  const q = [wa * a[0] * s + wb * b[0], wa * a[1] * s + wb * b[1], wa * a[2] * s + wb * b[2], wa * a[3] * s + wb * b[3]];
  const n = Math.hypot(q[0], q[1], q[2], q[3]) || 1;
  return [q[0] / n, q[1] / n, q[2] / n, q[3] / n];
}

// ------------------------------------------------------------------ motion
// A motion is {frames, joints, roots: Float32Array(frames*3), rots: Float32Array(frames*joints*4)}:
// flat typed arrays keep a few thousand poses cheap to slice, copy and send.

export function motionFromPoses(rootPositions, rotations) {
  const frames = rotations.length, joints = rotations[0].length;
  const roots = new Float32Array(frames * 3), rots = new Float32Array(frames * joints * 4);
  for (let f = 0; f < frames; f++) {
    roots.set(rootPositions[f], f * 3);
    for (let j = 0; j < joints; j++) rots.set(rotations[f][j], (f * joints + j) * 4);
  }
  return { frames, joints, roots, rots };
}

// Transition frames of POST /v1/transition ({root_position, rotations} each) as a motion.
export const motionFromFrames = (frames) => motionFromPoses(frames.map((p) => p.root_position), frames.map((p) => p.rotations));

export function emptyMotion(joints) {
  return { frames: 0, joints, roots: new Float32Array(0), rots: new Float32Array(0) };
}

export function poseAt(m, f) {
  return { root: Array.from(m.roots.subarray(f * 3, f * 3 + 3)), rots: m.rots.subarray(f * m.joints * 4, (f + 1) * m.joints * 4) };
}

export function sliceMotion(m, start, stop) {
  return { frames: stop - start, joints: m.joints, roots: m.roots.slice(start * 3, stop * 3),
           rots: m.rots.slice(start * m.joints * 4, stop * m.joints * 4) };
}

export function concatMotions(a, b) {
  const roots = new Float32Array((a.frames + b.frames) * 3), rots = new Float32Array(a.rots.length + b.rots.length);
  roots.set(a.roots); roots.set(b.roots, a.roots.length); rots.set(a.rots); rots.set(b.rots, a.rots.length);
  return { frames: a.frames + b.frames, joints: a.joints, roots, rots };
}

export function appendPose(m, root, rots, keep) {
  // A rolling history for live mode: keep only the last `keep` frames.
  const out = concatMotions(m, { frames: 1, joints: m.joints, roots: Float32Array.from(root), rots: Float32Array.from(rots) });
  return out.frames > keep ? sliceMotion(out, out.frames - keep, out.frames) : out;
}

// The contract's JSON pose Motion; 6 decimals keep quaternion norms well inside the server's tolerance.
export function motionPayload(m, start = 0, stop = m.frames) {
  const r6 = (v) => Math.round(v * 1e6) / 1e6;
  const rootPositions = [], rotations = [];
  for (let f = start; f < stop; f++) {
    rootPositions.push(Array.from(m.roots.subarray(f * 3, f * 3 + 3), r6));
    const row = [];
    for (let j = 0; j < m.joints; j++) row.push(Array.from(m.rots.subarray((f * m.joints + j) * 4, (f * m.joints + j) * 4 + 4), r6));
    rotations.push(row);
  }
  return { root_positions: rootPositions, rotations };
}

// ------------------------------------------------------------------ kinematics
// skeleton: {parents: Int32Array, offsets: [[x,y,z]]}, joints in GET /v1/model order (parents first).
export function forwardKinematics(skeleton, root, rots, out = new Float32Array(skeleton.parents.length * 3)) {
  const n = skeleton.parents.length;
  const grot = new Array(n);
  for (let j = 0; j < n; j++) {
    const q = [rots[j * 4], rots[j * 4 + 1], rots[j * 4 + 2], rots[j * 4 + 3]];
    const p = skeleton.parents[j];
    if (p < 0) {
      grot[j] = q;
      out[j * 3] = root[0]; out[j * 3 + 1] = root[1]; out[j * 3 + 2] = root[2];
    } else {
      grot[j] = qmul(grot[p], q);
      const o = qrot(grot[p], skeleton.offsets[j]);
      out[j * 3] = out[p * 3] + o[0]; out[j * 3 + 1] = out[p * 3 + 1] + o[1]; out[j * 3 + 2] = out[p * 3 + 2] + o[2];
    }
  }
  return out;
}

// World positions of every frame: [frames] of Float32Array(joints*3), computed once per motion.
export function motionPositions(skeleton, m) {
  const out = [];
  for (let f = 0; f < m.frames; f++) {
    const p = poseAt(m, f);
    out.push(forwardKinematics(skeleton, p.root, p.rots));
  }
  return out;
}

// Facing as the model defines it (model/motion/features.py): up x (right - left) of the hips and shoulders,
// so "face the clicked direction" means the same to the viewer and to the network.
export function facingYaw(skeleton, positions, rootRotation) {
  const r = skeleton.roles;
  if (!r) { // roles unknown (GET /v1/viewer/rig failed): assume the rig faces +Z at rest
    const f = qrot(rootRotation, [0, 0, 1]);
    return Math.atan2(f[0], f[2]);
  }
  const at = (j) => [positions[j * 3], positions[j * 3 + 1], positions[j * 3 + 2]];
  const across = add(sub(at(r.right_hip), at(r.left_hip)), sub(at(r.right_shoulder), at(r.left_shoulder)));
  return Math.atan2(across[2], -across[0]);
}

// ------------------------------------------------------------------ transitions
// The baseline of the paper's tables (model/evaluation/baselines.py interpolate): frame k of N lerps the root and
// slerps every local rotation k/N of the way from the last context pose to the target; frame N is the target.
export function interpolateBaseline(last, target, frames) {
  const j = last.rots.length / 4;
  const roots = new Float32Array(frames * 3), rots = new Float32Array(frames * j * 4);
  for (let k = 1; k <= frames; k++) {
    const t = k / frames;
    roots.set(lerp(last.root, target.root, t), (k - 1) * 3);
    for (let i = 0; i < j; i++) {
      const a = Array.from(last.rots.subarray(i * 4, i * 4 + 4)), b = Array.from(target.rots.subarray(i * 4, i * 4 + 4));
      rots.set(k === frames ? b : qslerp(a, b, t), ((k - 1) * j + i) * 4);
    }
  }
  return { frames, joints: j, roots, rots };
}

// Move a short motion (the target and the frame before it) rigidly so that its last frame stands on
// `point` (x, z; the height is kept) facing `yaw` (radians about +Y, 0 = +Z): a turn about the vertical
// through the last root, then a shift. The frame before keeps its offset, so the target's velocity
// turns with it.
export function placeMotion(skeleton, m, point, yaw) {
  const last = poseAt(m, m.frames - 1);
  const now = facingYaw(skeleton, forwardKinematics(skeleton, last.root, last.rots), Array.from(last.rots.subarray(0, 4)));
  const turn = yawQuat(yaw - now);
  const out = { frames: m.frames, joints: m.joints, roots: new Float32Array(m.roots.length), rots: Float32Array.from(m.rots) };
  for (let f = 0; f < m.frames; f++) {
    const p = poseAt(m, f);
    const d = qrot(turn, sub(p.root, last.root));
    out.roots.set([point[0] + d[0], p.root[1], point[2] + d[2]], f * 3);
    const q = qmul(turn, Array.from(p.rots.subarray(0, 4)));
    out.rots.set(q, f * m.joints * 4);
  }
  return out;
}
