// Shared widgets: the status line, the timeline player, pointer controls on the 3D view, and the style
// picker that both modes use.

export const $ = (id) => document.getElementById(id);

export function status(text, kind = "") {
  const el = $("status");
  el.textContent = text;
  el.className = kind;
}

// ------------------------------------------------------------------ timeline
// Plays a sequence of `length` frames at `fps` x speed; the displayed frame is floor(position).
export class Player {
  constructor(fps) {
    this.fps = fps;
    this.length = 0;
    this.position = 0;
    this.playing = false;
    this.els = { play: $("play"), scrub: $("scrub"), time: $("time"), speed: $("speed"), loop: $("loop") };
    this.els.play.addEventListener("click", () => this.toggle());
    this.els.scrub.addEventListener("input", () => {
      this.position = Number(this.els.scrub.value);
      this.playing = false;
      this.sync();
    });
  }

  get frame() { return Math.min(this.length - 1, Math.max(0, Math.floor(this.position))); }
  get speed() { return Number(this.els.speed.value); }

  load(length, { play = true, at = 0 } = {}) {
    this.length = length;
    this.position = at;
    this.playing = play && length > 1;
    this.els.scrub.max = String(Math.max(0, length - 1));
    this.sync();
  }

  toggle() {
    if (this.length < 2) return;
    if (!this.playing && this.frame >= this.length - 1) this.position = 0; // play again from the start
    this.playing = !this.playing;
    this.sync();
  }

  tick(dt) {
    if (!this.playing || this.length < 2) return;
    this.position += dt * this.fps * this.speed;
    if (this.position >= this.length) {
      if (this.els.loop.checked) this.position %= this.length;
      else { this.position = this.length - 1; this.playing = false; }
    }
    this.sync();
  }

  sync() {
    const f = this.frame;
    this.els.play.textContent = this.playing ? "❚❚" : "▶";
    this.els.scrub.value = String(f);
    this.els.time.textContent = `${f + 1} / ${this.length} · ${(f / this.fps).toFixed(2)} s`;
  }
}

// ------------------------------------------------------------------ pointer controls
// Drag orbits, right- or shift-drag pans, the wheel zooms. A press that barely moves is a click on the
// ground (onClick); while `placing` is set, press-drag-release places a point and a facing instead
// (onPlace(point, yaw, done)). Pointer capture keeps a drag going when it leaves the canvas.
export class ViewControls {
  constructor(canvas, renderer, camera) {
    this.canvas = canvas; this.renderer = renderer; this.camera = camera;
    this.onClick = null; this.onPlace = null; this.placing = false;
    this.pressed = false; // while a pointer is down (or a target is being placed) the camera must not follow
    let down = null;
    const local = (ev) => { const r = canvas.getBoundingClientRect(); return [ev.clientX - r.left, ev.clientY - r.top]; };
    canvas.addEventListener("contextmenu", (ev) => ev.preventDefault());
    canvas.addEventListener("pointerdown", (ev) => {
      canvas.setPointerCapture(ev.pointerId);
      const [x, y] = local(ev);
      this.pressed = true;
      down = { x, y, lastX: x, lastY: y, moved: 0, pan: ev.button === 2 || ev.shiftKey,
               place: this.placing ? renderer.pickGround(x, y) : null };
    });
    canvas.addEventListener("pointermove", (ev) => {
      if (!down) return;
      const [x, y] = local(ev);
      const dx = x - down.lastX, dy = y - down.lastY;
      down.lastX = x; down.lastY = y; down.moved += Math.abs(dx) + Math.abs(dy);
      if (down.place) this.place(down.place, x, y, false);
      else if (down.pan) camera.pan(dx, dy);
      else camera.orbit(dx, dy);
    });
    canvas.addEventListener("pointerup", (ev) => {
      if (!down) return;
      const [x, y] = local(ev);
      if (down.place) this.place(down.place, x, y, true);
      else if (down.moved < 5 && this.onClick) {
        const p = renderer.pickGround(x, y);
        if (p) this.onClick(p);
      }
      down = null;
      this.pressed = false;
    });
    canvas.addEventListener("pointercancel", () => { down = null; this.pressed = false; });
    canvas.addEventListener("wheel", (ev) => { ev.preventDefault(); camera.zoom(Math.exp(ev.deltaY * 0.0012)); }, { passive: false });
  }

  place(start, x, y, done) {
    const p = this.renderer.pickGround(x, y);
    let yaw = null;
    if (p && Math.hypot(p[0] - start[0], p[2] - start[2]) > 8) yaw = Math.atan2(p[0] - start[0], p[2] - start[2]);
    this.onPlace?.(start, yaw, done);
    if (done) this.setPlacing(false);
  }

  // The camera follows a character only while nobody is pointing at the ground.
  get still() { return this.pressed || this.placing; }

  setPlacing(on) {
    this.placing = on;
    this.canvas.classList.toggle("placing", on);
  }
}

// ------------------------------------------------------------------ styles
// The model's built-in styles (GET /v1/model builtin_styles: ids "builtin:NAME", usable at once), the styles
// registered on the server (GET /v1/styles) and the demo style clips, which are registered (POST /v1/styles)
// the first time they are chosen; uploads are registered at once. Option values are "id:<style_id>" or
// "demo:<name>". An upload longer than the model reads (style_clip_frames.max at its fps) is cut to its middle
// frames, as the Python, Unity and Unreal clients cut one, and the page says so; an upload that fails leaves no
// style chosen, so Generate cannot quietly use the one chosen before.
export class StylePicker {
  constructor(api, demos, selects, builtins = [], model = null) {
    this.api = api;
    this.builtins = builtins;
    this.maxFrames = model && model.style_clip_frames ? model.style_clip_frames.max : null;
    this.demos = demos.filter((d) => d.kind === "style");
    this.selects = selects;
    this.styles = [];
  }

  // Reload the list; `select` (one of the pickers) is set to `value`, the others keep their choice.
  async refresh(select = null, value = null) {
    const { styles } = await this.api.styles();
    this.styles = styles;
    for (const sel of this.selects) {
      const keep = sel === select && value ? value : sel.value;
      sel.innerHTML = "";
      for (const b of this.builtins) sel.add(new Option(`${b.name} (built-in, ${b.frames} frames)`, `id:${b.style_id}`));
      // GET /v1/styles lists the built-in styles too ("builtin": true): they are in the list once, above.
      for (const s of this.styles.filter((s) => !s.builtin)) sel.add(new Option(`${s.name} (${s.frames} frames)`, `id:${s.style_id}`));
      const registered = new Set([...this.builtins, ...this.styles].map((s) => s.name));
      for (const d of this.demos) {
        if (!registered.has(d.name)) sel.add(new Option(`${d.name} (demo, registered on use)`, `demo:${d.name}`));
      }
      if ([...sel.options].some((o) => o.value === keep)) sel.value = keep;
    }
  }

  // The style_id chosen in `select`, registering a demo clip when needed.
  async resolve(select) {
    const value = select.value;
    if (!value) throw new Error("pick a style (or upload a style BVH)");
    if (value.startsWith("id:")) return value.slice(3);
    const name = value.slice(5);
    const clip = await this.api.demo(name);
    const info = await this.api.registerStyle(name, { root_positions: clip.root_positions, rotations: clip.rotations });
    await this.refresh(select, `id:${info.style_id}`);
    return info.style_id;
  }

  // Registers a style BVH; resolves to the POST /v1/styles answer plus `cut`: {from, start, frames} when the clip
  // was longer than the model reads and its middle was sent, else null.
  async upload(file, select) {
    const name = file.name.replace(/\.bvh$/i, "");
    try {
      const text = await file.text();
      let motion = { bvh: text }, cut = null;
      if (this.maxFrames) {
        // The clip on the model's rig at its fps (POST /v1/viewer/clip), to count the frames the model would read.
        const clip = await this.api.readTake(file.name, text);
        if (clip.frames > this.maxFrames) {
          const start = Math.floor((clip.frames - this.maxFrames) / 2), stop = start + this.maxFrames;
          cut = { from: clip.frames, start, frames: this.maxFrames, fps: clip.fps };
          motion = { root_positions: clip.root_positions.slice(start, stop), rotations: clip.rotations.slice(start, stop),
                     fps: clip.fps };
        }
      }
      const info = await this.api.registerStyle(name, motion);
      await this.refresh(select, `id:${info.style_id}`);
      return { ...info, cut };
    } catch (err) {
      // Nothing chosen in place of the style that failed: Generate asks for one instead of using the previous.
      const failed = new Option(`${file.name}: not registered (see the error)`, "");
      select.add(failed, 0);
      select.value = "";
      throw new Error(`style ${file.name} was not registered: ${err.message}`);
    }
  }
}
