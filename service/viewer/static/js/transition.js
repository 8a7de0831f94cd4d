// Transition mode: pick a take, a context point and a target, generate with POST /v1/transition and
// watch the model beside the interpolation baseline and, when the target is a frame of the take, the
// take's own frames (the ground truth). Export sends the same request with output "bvh": the same
// seed gives the same frames, so the file is what was shown.

import {
  concatMotions, interpolateBaseline, motionFromFrames, motionFromPoses, motionPayload, motionPositions, placeMotion, poseAt,
  sliceMotion,
} from "./math.js";
import { $, status } from "./ui.js";

const COLORS = { take: "#c9d1dc", model: "#4da3ff", baseline: "#f2a93b", truth: "#5fd38d", context: "#8b95a3", target: "#e45f8f" };
const LEAD_IN = 30; // frames of the take shown before the transition starts

export class TransitionMode {
  constructor(app) {
    this.app = app;
    this.take = null;      // {name, motion, positions}
    this.ground = null;    // {point, yaw} when the target is placed on the ground
    this.result = null;    // {tracks, request, timing}
    this.lastExport = null;
    this.busy = false;
    this.els = {
      takeSelect: $("take-select"), takeFile: $("take-file"), context: $("context-frame"), contextOut: $("context-frame-out"),
      frames: $("frames"), framesOut: $("frames-out"), place: $("place-target"), style: $("style-select"),
      styleFile: $("style-file"), styleNote: $("style-note"), seed: $("seed"), deterministic: $("deterministic"), generate: $("generate"),
      exportBtn: $("export"), showTake: $("show-take"), sideBySide: $("side-by-side"), follow: $("follow"),
      info: $("transition-info"),
    };
    this.els.frames.max = String(app.model.max_transition_frames);
    this.els.seed.value = String(Math.floor(Math.random() * 100000));
    this.bind();
  }

  bind() {
    const e = this.els, app = this.app;
    for (const d of app.demos.filter((x) => x.kind === "take")) e.takeSelect.add(new Option(`${d.name}: ${d.description}`, d.name));
    e.takeSelect.addEventListener("change", () => this.run(() => this.loadDemo(e.takeSelect.value)));
    e.takeFile.addEventListener("change", () => e.takeFile.files[0] && this.run(() => this.loadUpload(e.takeFile.files[0])));
    e.styleFile.addEventListener("change", () => e.styleFile.files[0] && this.run(async () => {
      const file = e.styleFile.files[0];
      e.styleFile.value = "";  // choosing the same file again (after fixing it) uploads it again
      e.styleNote.textContent = "";
      let info;
      try { info = await app.styles.upload(file, e.style); } catch (err) { e.styleNote.textContent = err.message; throw err; }
      const cut = info.cut ? `; the clip has ${info.cut.from} frames at ${info.cut.fps} fps and the model reads at most ` +
        `${info.cut.frames}: its middle ${info.cut.frames} (frames ${info.cut.start}-${info.cut.start + info.cut.frames - 1}) ` +
        "were sent, as the clients cut a long clip (cut it yourself to choose the part)" : "";
      e.styleNote.textContent = info.cut ? `style ${info.name}: cut to the middle ${info.cut.frames} of ${info.cut.from} frames` : "";
      status(`registered style ${info.name} (${info.frames} frames${info.cached ? ", already cached" : ""})${cut}`, "ok");
    }));
    e.context.addEventListener("input", () => this.changed());
    e.frames.addEventListener("input", () => this.changed());
    for (const r of document.querySelectorAll('input[name="target-kind"]')) r.addEventListener("change", () => this.changed());
    e.place.addEventListener("click", () => {
      app.controls.setPlacing(true);
      status("press on the ground, drag towards the facing, release");
    });
    e.generate.addEventListener("click", () => this.run(() => this.generate()));
    e.exportBtn.addEventListener("click", () => this.run(() => this.exportBvh()));
    e.showTake.addEventListener("change", () => this.showSequence());
  }

  // Runs an action with the buttons disabled, reporting failures on the status line.
  async run(fn) {
    if (this.busy) return;
    this.busy = true;
    this.els.generate.disabled = true;
    try { await fn(); } catch (err) { status(err.message, "error"); this.app.errors.push(err.message); } finally {
      this.busy = false;
      this.els.generate.disabled = false;
    }
  }

  activate() {
    this.app.controls.onClick = null;
    this.app.controls.onPlace = (point, yaw, done) => {
      this.ground = { point, yaw: yaw ?? (this.ground ? this.ground.yaw : 0) };
      if (done) { status(`target placed at x ${point[0].toFixed(0)} cm, z ${point[2].toFixed(0)} cm`, "ok"); this.changed(); }
    };
    this.showSequence();
  }

  get targetKind() { return document.querySelector('input[name="target-kind"]:checked').value; }

  async loadDemo(name) {
    status(`loading demo take ${name}… (the model generates a style's takes on their first load: a few seconds)`);
    this.setTake(await this.app.api.demo(name));
    status(`demo take ${name}: ${this.take.motion.frames} frames`, "ok");
  }

  async loadUpload(file) {
    status(`reading ${file.name}…`);
    const clip = await this.app.api.readTake(file.name, await file.text());
    const opt = new Option(`${file.name} (uploaded)`, `upload:${file.name}`);
    this.els.takeSelect.add(opt);
    this.els.takeSelect.value = opt.value;
    this.setTake(clip);
    status(`${file.name}: ${clip.frames} frames at ${clip.fps} fps on the model's rig`, "ok");
  }

  setTake(clip) {
    const motion = motionFromPoses(clip.root_positions, clip.rotations);
    this.take = { name: clip.name, motion, positions: motionPositions(this.app.skeleton, motion) };
    this.app.take = this.take;
    const ctx = this.app.model.context_frames, e = this.els;
    e.context.min = String(ctx - 1);
    e.context.max = String(Math.max(ctx - 1, motion.frames - 2));
    e.context.value = String(Math.min(Number(e.context.max), Math.max(ctx - 1, Math.round(motion.frames / 3))));
    this.ground = null;
    this.result = null;
    this.changed();
  }

  // Keep the inputs consistent: with a take target, the target frame is context + frames.
  changed() {
    const e = this.els, m = this.take && this.take.motion;
    if (!m) return;
    const c = Number(e.context.value);
    let n = Math.max(1, Math.min(Number(e.frames.value) || 1, this.app.model.max_transition_frames));
    const fromTake = this.targetKind === "take";
    if (fromTake) n = Math.min(n, m.frames - 1 - c);
    if (String(n) !== e.frames.value) e.frames.value = String(n);
    e.contextOut.textContent = `${c} (${(c / this.app.model.fps).toFixed(2)} s)`;
    e.framesOut.textContent = fromTake ? `→ target frame ${c + n}` : `${(n / this.app.model.fps).toFixed(2)} s`;
    e.place.disabled = fromTake;
    // A new choice is shown on the take at once; the last result stays one tick away ("the take, not the result").
    if (this.result) e.showTake.checked = true;
    this.showSequence();
  }

  request(output) {
    const m = this.take.motion, c = Number(this.els.context.value), n = Number(this.els.frames.value);
    const ctx = this.app.model.context_frames;
    const context = motionPayload(m, c - ctx + 1, c + 1);
    let targetMotion;
    if (this.targetKind === "take") {
      targetMotion = sliceMotion(m, c + n - 1, c + n + 1); // the target and the frame before it (its velocity)
    } else {
      if (!this.ground) throw new Error("place the target on the ground first (or choose a later frame of the take)");
      // The pose of the take at context + frames, when there is one, else the context pose, moved there.
      const t = Math.min(c + n, m.frames - 1);
      targetMotion = placeMotion(this.app.skeleton, sliceMotion(m, t - 1, t + 1), this.ground.point, this.ground.yaw);
    }
    return { body: { context, target: motionPayload(targetMotion), frames: n, seed: Number(this.els.seed.value) || 0,
                     deterministic: this.els.deterministic.checked, output }, targetMotion, c, n,
             fromTake: this.targetKind === "take" };
  }

  async generate() {
    if (!this.take) throw new Error("load a take first");
    const req = this.request("json");
    status("registering the style…");
    req.body.style_id = await this.app.styles.resolve(this.els.style);
    status(`generating ${req.n} frames…`);
    const res = await this.app.api.transition(req.body);
    const m = this.take.motion, sk = this.app.skeleton;
    const leadStart = Math.max(0, req.c - LEAD_IN + 1);
    const lead = sliceMotion(m, leadStart, req.c + 1);
    const generated = motionFromFrames(res.frames);
    const target = poseAt(req.targetMotion, req.targetMotion.frames - 1);
    const baseline = interpolateBaseline(poseAt(m, req.c), target, req.n);
    const tracks = [
      track("RSMT", COLORS.model, concatMotions(lead, generated), sk),
      track("interpolation", COLORS.baseline, concatMotions(lead, baseline), sk),
    ];
    if (req.fromTake) tracks.push(track("ground truth", COLORS.truth, sliceMotion(m, leadStart, req.c + req.n + 1), sk));
    this.result = { tracks, request: req, lead: lead.frames, timing: res.timing_ms,
                    targetPositions: motionPositions(sk, req.targetMotion).at(-1) };
    this.els.exportBtn.disabled = false;
    this.els.showTake.checked = false;
    const t = res.timing_ms;
    this.els.info.textContent = `${req.n} frames, style ${res.style_id.slice(0, 12)}…, seed ${res.seed}; ` +
      `server ${t.total} ms (engine ${t.engine} ms, ${t.per_frame} ms/frame)`;
    this.showSequence();
    status(`generated ${req.n} frames in ${res.timing_ms.total} ms`, "ok");
  }

  async exportBvh() {
    if (!this.result) throw new Error("generate a transition first");
    // The same request, seed included, with output "bvh": the same frames as those shown.
    const res = await this.app.api.transition({ ...this.result.request.body, output: "bvh" });
    const frames = Number((/Frames:\s*(\d+)/.exec(res.bvh) || [])[1]);
    this.lastExport = { frames, bytes: res.bvh.length };
    const a = document.createElement("a");
    a.href = URL.createObjectURL(new Blob([res.bvh], { type: "text/plain" }));
    a.download = `rsmt-${this.take.name.replace(/\.bvh$/i, "")}-${this.result.request.c}-${this.result.request.n}.bvh`;
    document.body.appendChild(a); a.click(); a.remove();
    setTimeout(() => URL.revokeObjectURL(a.href), 10000);
    status(`exported ${frames} frames as ${a.download}`, "ok");
  }

  // What the timeline plays: the result when there is one (unless "show the take" is ticked), else the take.
  showSequence() {
    const player = this.app.player;
    const showResult = this.result && !this.els.showTake.checked;
    const length = showResult ? Math.max(...this.result.tracks.map((t) => t.positions.length)) : this.take ? this.take.motion.frames : 0;
    const at = showResult ? 0 : Number(this.els.context.value) || 0;
    if (this.shown !== (showResult ? this.result : this.take)) {
      this.shown = showResult ? this.result : this.take;
      player.load(length, { play: !!showResult, at });
    }
    this.legend(showResult ? this.result.tracks : [{ name: "take", color: COLORS.take }]);
  }

  legend(tracks) {
    $("legend").innerHTML = tracks.map((t) => `<span style="color:${t.color}">${t.name}</span>`).join("");
  }

  // The scene of the current frame, for the renderer.
  scene() {
    const sk = this.app.skeleton, f = this.app.player.frame, scene = { skeletons: [], markers: [], trails: [] };
    const base = { parents: sk.parents, side: sk.side };
    if (this.result && !this.els.showTake.checked) {
      const r = this.result, tracks = r.tracks, side = this.els.sideBySide.checked;
      const offsets = sideOffsets(tracks.length, side ? lateral(r) : [0, 0, 0]);
      tracks.forEach((t, i) => {
        const pos = shift(t.positions[Math.min(f, t.positions.length - 1)], offsets[i]);
        scene.skeletons.push({ ...base, positions: pos, color: t.color, label: side || i === 0 ? t.name : null });
        scene.trails.push({ points: t.roots.map((p) => [p[0] + offsets[i][0], 0.3, p[2] + offsets[i][2]]), color: t.color });
        // The target pose, faint, where each track should arrive.
        scene.skeletons.push({ ...base, positions: shift(r.targetPositions, offsets[i]), color: COLORS.target, alpha: 0.25, width: 3 });
      });
      // The side-by-side offsets are symmetric about zero: following the first track's own path keeps all in view.
      const lead = tracks[0].roots;
      if (this.els.follow.checked && !this.app.controls.still) this.app.camera.follow(lead[Math.min(f, lead.length - 1)]);
      return scene;
    }
    if (!this.take) return scene;
    const m = this.take, c = Number(this.els.context.value), n = Number(this.els.frames.value);
    scene.skeletons.push({ ...base, positions: m.positions[Math.min(f, m.motion.frames - 1)], color: COLORS.take, label: "take" });
    scene.skeletons.push({ ...base, positions: m.positions[c], color: COLORS.context, alpha: 0.35, width: 3, label: "context" });
    if (this.targetKind === "take" && c + n < m.motion.frames) {
      scene.skeletons.push({ ...base, positions: m.positions[c + n], color: COLORS.target, alpha: 0.35, width: 3, label: "target" });
    } else if (this.ground) {
      scene.markers.push({ point: this.ground.point, yaw: this.ground.yaw, color: COLORS.target, label: "target" });
    }
    scene.trails.push({ points: m.positions.map((p) => [p[0], 0.3, p[2]]), color: COLORS.take });
    if (this.els.follow.checked && !this.app.controls.still) this.app.camera.follow(m.positions[Math.min(f, m.motion.frames - 1)]);
    return scene;
  }
}

function track(name, color, motion, sk) {
  const roots = [];
  for (let f = 0; f < motion.frames; f++) roots.push(Array.from(motion.roots.subarray(f * 3, f * 3 + 3)));
  return { name, color, positions: motionPositions(sk, motion), roots };
}

// Side by side means across the direction of travel, so the characters never walk through each other.
function lateral(result) {
  const t = result.tracks[0].roots, a = t[result.lead - 1] || t[0], b = t.at(-1);
  let d = [b[0] - a[0], b[2] - a[2]];
  const n = Math.hypot(d[0], d[1]);
  d = n > 1 ? [d[0] / n, d[1] / n] : [0, 1];
  return [d[1] * 140, 0, -d[0] * 140];
}

function sideOffsets(count, step) {
  return Array.from({ length: count }, (_, i) => { const k = i - (count - 1) / 2; return [step[0] * k, 0, step[2] * k]; });
}

function shift(positions, o) {
  if (!o[0] && !o[2]) return positions;
  const out = new Float32Array(positions.length);
  for (let i = 0; i < positions.length; i += 3) {
    out[i] = positions[i] + o[0]; out[i + 1] = positions[i + 1]; out[i + 2] = positions[i + 2] + o[2];
  }
  return out;
}
