// Live mode: one character streamed over /v1/stream (binary frames) walks to where the ground is clicked.
// A click while it walks sends `retarget`; a click after it arrived starts a new transition from its last
// poses. Either way the target is a pose of the take (motion on the model's rig, standing on its
// floor) turned to face the click and moved there, and the character arrives on it exactly
// (`exact_arrival`). Chained clicks used to leave a crumpled figure floating 20-60 cm up: the target was
// the character's own last pose, a generated pose that arrives several centimetres off (often above) its
// target, and the next context ended on that miss, so each click inherited and extended the last one.
// Now every walk ends on the same pose of the take, and the next one starts from it. The style picker sends
// `style` on the fly. The HUD shows how late frames arrive against the server's clock.

import { appendPose, facingYaw, forwardKinematics, motionPayload, placeMotion, sliceMotion } from "./math.js";
import { $, status } from "./ui.js";
import { LiveStream } from "./transport.js";

const HISTORY = 60;        // frames kept: the next start's context and the trail
const TRAIL = 240;
const MIN_FRAMES = 15;     // shortest walk to a click, so even a near click gets a visible transition
const MAX_FRAMES = 60;     // longest: models are trained on transitions up to 60 frames; past that a far click is walked faster
const COLOR = "#4da3ff", DEST = "#e45f8f";

export class LiveMode {
  constructor(app) {
    this.app = app;
    this.stream = null;
    this.character = null; // id of the live character, null when none walks
    this.slot = null;
    this.history = null;   // recent poses (a motion): the current pose is the last
    this.positions = null; // world positions of the current pose
    this.trail = [];
    this.dest = null;
    this.seq = 0;
    this.stats = this.freshStats();
    this.starts = 0;
    this.els = { style: $("live-style"), speed: $("live-speed"), start: $("live-start"), stop: $("live-stop"), hud: $("hud") };
    this.els.start.addEventListener("click", () => this.guard(() => this.goTo(null)));
    this.els.stop.addEventListener("click", () => this.stop());
    this.els.style.addEventListener("change", () => this.guard(() => this.switchStyle()));
  }

  freshStats() {
    return { frames: 0, arrivals: [], lateness: [], t0: null, arrived0: null, lastLateness: null, retargets: 0, styleChanges: 0,
             reach: null, outOfReach: 0, ended: null };
  }

  async guard(fn) {
    try { await fn(); } catch (err) { status(err.message, "error"); this.app.errors.push(err.message); }
  }

  activate() {
    this.app.controls.onPlace = null;
    this.app.controls.setPlacing(false);
    this.app.controls.onClick = (p) => this.guard(() => this.goTo(p));
    this.els.hud.hidden = false;
    $("legend").innerHTML = `<span style="color:${COLOR}">live character</span><span style="color:${DEST}">destination</span>`;
    if (!this.history && this.app.take) this.resetHistory();
  }

  deactivate() { this.els.hud.hidden = true; }

  resetHistory() {
    // The first context: the opening frames of the current take (a person standing, for the takes a model
    // generates from a standing pose; a walk on the synthetic test rig).
    const take = this.app.take.motion, n = Math.min(take.frames, Math.max(this.app.model.context_frames, 2));
    this.history = sliceMotion(take, 0, n);
    this.updatePose();
  }

  // The target's two frames (the pose and the one before it, for its velocity): the frames of the take where
  // the first context ends, so every walk arrives in the pose (standing, or in the gait) the character started in.
  targetPose() {
    const take = this.app.take.motion, f = Math.min(take.frames, Math.max(this.app.model.context_frames, 2));
    return sliceMotion(take, f - 2, f);
  }

  updatePose() {
    const m = this.history, f = m.frames - 1;
    const root = Array.from(m.roots.subarray(f * 3, f * 3 + 3));
    this.positions = forwardKinematics(this.app.skeleton, root, m.rots.subarray(f * m.joints * 4));
  }

  async connect() {
    if (this.stream && this.stream.open) return;
    this.stream = new LiveStream(this.app.api, {
      onFrame: (fr) => this.onFrame(fr),
      onMessage: (msg) => this.onMessage(msg),
      onClose: (code, reason) => {
        this.character = null;
        clearInterval(this.pinger);
        this.els.stop.disabled = true;
        if (code !== 1000 || reason !== "viewer closed the stream") {
          status(`stream closed (${code}${reason ? ": " + reason : ""}); click to reconnect`);
        }
      },
    });
    await this.stream.connect();
    // Pings give the round trip; they also keep an idle connection (no live character) from timing out.
    this.pinger = setInterval(() => this.stream.open && this.stream.ping(), 2000);
    this.stream.ping();
  }

  // Walk to `point` (null: 2.5 m ahead of where the character faces).
  async goTo(point) {
    if (!this.history) {
      if (!this.app.take) throw new Error("load or upload a take first: its opening frames are where the character starts");
      this.resetHistory();
    }
    await this.connect();
    const m = this.history, f = m.frames - 1, sk = this.app.skeleton;
    const here = [m.roots[f * 3], 0, m.roots[f * 3 + 2]];
    const facing = facingYaw(sk, this.positions, Array.from(m.rots.subarray(f * m.joints * 4, f * m.joints * 4 + 4)));
    if (!point) point = [here[0] + 250 * Math.sin(facing), 0, here[2] + 250 * Math.cos(facing)];
    const dist = Math.hypot(point[0] - here[0], point[2] - here[2]);
    const yaw = dist > 1 ? Math.atan2(point[0] - here[0], point[2] - here[2]) : facing; // a click on the spot keeps it
    const speed = Math.max(30, Number(this.els.speed.value) || 130), fps = this.app.model.fps;
    const longest = Math.min(this.app.model.max_transition_frames, MAX_FRAMES);
    const frames = Math.round(Math.min(longest, Math.max(MIN_FRAMES, (dist / speed) * fps)));
    const target = motionPayload(placeMotion(sk, this.targetPose(), point, yaw));
    this.dest = { point, yaw };
    if (this.character) {
      this.stream.send({ type: "retarget", character: this.character, target, frames });
      this.stats.retargets += 1;
      status(`retargeted: ${(dist / 100).toFixed(1)} m in ${frames} frames`);
      return;
    }
    // A start waits for the style (a demo style is registered first): clicks meanwhile are ignored, not doubled.
    if (this.starting) return;
    this.starting = true;
    try {
      const ctx = this.app.model.context_frames;
      const styleId = await this.app.styles.resolve(this.els.style);
      const id = `walker-${++this.starts}`;
      this.stream.send({ type: "start", character: id, context: motionPayload(m, m.frames - ctx, m.frames), target, frames,
                         style_id: styleId, exact_arrival: true, pace: "realtime" });
      this.character = id;
      this.slot = null;
      status(`walking ${(dist / 100).toFixed(1)} m in ${frames} frames…`);
    } finally {
      this.starting = false;
    }
  }

  async switchStyle() {
    if (!this.character) return;
    const styleId = await this.app.styles.resolve(this.els.style);
    this.stream.send({ type: "style", character: this.character, style_id: styleId });
  }

  stop() {
    if (this.character && this.stream && this.stream.open) this.stream.send({ type: "cancel", character: this.character });
    if (this.stream) this.stream.close();
    this.character = null;
  }

  // The server's reach notice of a start, retarget or style switch: a click farther than the style's capture speed
  // covers in the frames asked (or left) is not reached (the character arrives short rather than glide), and the
  // person is told; a switch to a slower style can put a walk out of reach.
  showReach(reach) {
    this.stats.reach = reach || null;
    if (!reach || reach.feasible) return;
    this.stats.outOfReach += 1;
    const m = (cm) => (cm / 100).toFixed(1);
    status(`out of reach: ${m(reach.distance_cm)} m needs ${reach.needed_frames} frames at this style's top speed ` +
           `(${m(reach.max_speed_cm_s)} m/s), not ${reach.frames}: it stops short, at most ${m(reach.reachable_cm)} m on`, "error");
  }

  // The end of a walk: "arrived" only where the last reach notice (of the click, a retarget or a style switch) said within reach;
  // otherwise the root went as far as the style's capture speed allows and stopped short of the marker, by at
  // least what the notice says (the gait does not keep to its top speed the whole way).
  showEnd(reason) {
    const r = this.stats.reach, m = (cm) => (cm / 100).toFixed(2);
    if (reason !== "arrived") {
      this.stats.ended = reason;
      status(reason, "ok");
    } else if (r && !r.feasible) {
      const h = this.history, f = h.frames - 1, p = this.dest ? this.dest.point : null;
      const left = p ? Math.hypot(p[0] - h.roots[f * 3], p[2] - h.roots[f * 3 + 2]) : r.distance_cm - r.reachable_cm;
      this.stats.ended = "stopped short";
      status(`stopped short: ${m(left)} m from the marker, out of reach (${m(r.distance_cm)} m away; this style's top ` +
             `speed covers at most ${m(r.reachable_cm)} m in ${r.frames} frames); click the ground to walk again`, "error");
    } else {
      this.stats.ended = "arrived";
      status("arrived: click the ground to walk again", "ok");
    }
  }

  onMessage(msg) {
    if (msg.type === "started" && msg.character === this.character) {
      this.slot = msg.slot;
      this.stats.t0 = null; // the server's t restarts with every character
      this.stats.ended = null;
      this.els.stop.disabled = false;
      this.showReach(msg.reach);
    } else if (msg.type === "retargeted" && msg.character === this.character) {
      this.showReach(msg.reach);
    } else if (msg.type === "end" && msg.character === this.character) {
      this.character = null;
      this.els.stop.disabled = true;
      this.showEnd(msg.reason);
    } else if (msg.type === "style_changed") {
      this.stats.styleChanges += 1;
      status(`style switched from frame ${msg.from_seq}`, "ok");
      if (msg.character === this.character) this.showReach(msg.reach);
    } else if (msg.type === "error") {
      if (msg.character && msg.character === this.character) this.character = null;
      status(`${msg.code}: ${msg.message}`, "error");
      this.app.errors.push(`${msg.code}: ${msg.message}`);
    }
  }

  onFrame(fr) {
    if (fr.slot !== this.slot) return; // a frame of a character already replaced
    const s = this.stats;
    // Lateness: arrival against the server's schedule, both measured from this character's first frame.
    if (s.t0 === null) { s.t0 = fr.t; s.arrived0 = fr.arrived; }
    const late = fr.arrived - s.arrived0 - (fr.t - s.t0) * 1000;
    s.lastLateness = late;
    s.lateness.push(late); if (s.lateness.length > 90) s.lateness.shift();
    s.arrivals.push(fr.arrived); while (s.arrivals.length && s.arrivals[0] < fr.arrived - 1000) s.arrivals.shift();
    s.frames += 1;
    this.seq = fr.seq;
    this.remaining = fr.remaining;
    this.history = appendPose(this.history, fr.root, fr.rots, HISTORY);
    this.updatePose();
    this.trail.push([fr.root[0], 0.3, fr.root[2]]); if (this.trail.length > TRAIL) this.trail.shift();
  }

  info() {
    const s = this.stats, sorted = [...s.lateness].sort((a, b) => a - b);
    return {
      connected: !!(this.stream && this.stream.open), character: this.character, frames: s.frames, seq: this.seq,
      remaining: this.remaining ?? null, fps: s.arrivals.length, latenessMs: s.lastLateness,
      latenessP50Ms: sorted.length ? sorted[Math.floor(sorted.length / 2)] : null, rttMs: this.stream ? this.stream.rttMs : null,
      retargets: s.retargets, styleChanges: s.styleChanges, reach: s.reach, outOfReach: s.outOfReach, ended: s.ended,
    };
  }

  scene(renderFps) {
    const i = this.info(), f = (v, d = 1) => (v === null || v === undefined ? "–" : v.toFixed(d));
    this.els.hud.textContent = `${i.character ? "walking" : i.connected ? "standing" : "not connected"}` +
      `\nframes ${i.frames} (seq ${i.seq}, ${i.remaining ?? "–"} left)\nstream ${i.fps} fps · render ${f(renderFps, 0)} fps` +
      `\nlatency: arrival − server t ${f(i.latenessMs)} ms (p50 ${f(i.latenessP50Ms)}), vs frame 0\nping round trip ${f(i.rttMs)} ms`;
    const sk = this.app.skeleton, scene = { skeletons: [], markers: [], trails: [{ points: this.trail, color: COLOR }] };
    if (this.positions) {
      scene.skeletons.push({ parents: sk.parents, side: sk.side, positions: this.positions, color: COLOR,
                             label: i.character ? "streaming" : null });
      if (!this.app.controls.still) this.app.camera.follow(this.positions, 0.05);
    }
    if (this.dest) scene.markers.push({ point: this.dest.point, yaw: this.dest.yaw, color: DEST });
    return scene;
  }
}
