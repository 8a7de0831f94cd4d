// Start-up and the frame loop: read the model (skeleton, fps, limits) and the rig's roles, load the
// first demo take, then draw the active mode every animation frame. `window.rsmtViewer` exposes the
// state for people poking at it in the console and for the browser tests.

import { ApiError, Api } from "./transport.js";
import { LiveMode } from "./live.js";
import { OrbitCamera, Renderer } from "./renderer.js";
import { TransitionMode } from "./transition.js";
import { $, Player, StylePicker, ViewControls, status } from "./ui.js";

async function boot() {
  const api = new Api();
  const keyInput = $("api-key");
  keyInput.value = api.key;
  $("api-key-save").addEventListener("click", () => { api.setKey(keyInput.value); window.location.reload(); });

  let model, rig = null, demos;
  try {
    model = await api.model();
    [rig, demos] = await Promise.all([api.rig().catch(() => null), api.demos()]);
  } catch (err) {
    if (err instanceof ApiError && err.status === 401) {
      $("key-box").open = true;
      status("this server needs an API key: enter it above", "error");
    } else status(err.message, "error");
    window.rsmtViewer = { ready: false, error: err.message };
    return;
  }
  const joints = model.skeleton.joints;
  const parents = Int32Array.from(joints.map((j) => j.parent));
  const skeleton = {
    names: joints.map((j) => j.name), parents, offsets: joints.map((j) => j.offset),
    roles: rig ? rig.roles : null,
    side: rig ? sideOf(rig.roles, parents) : null, // -1 on the left: drawn darker, so handedness reads at a glance
  };
  $("model-info").textContent = `${model.name} ${model.version} · ${joints.length} joints · ${model.fps} fps · ` +
    `context ${model.context_frames} frames · up to ${model.max_transition_frames} frames · ` +
    `${model.skeleton.units}, ${model.skeleton.up_axis} up`;

  const canvas = $("view"), camera = new OrbitCamera(), renderer = new Renderer(canvas, camera);
  const app = {
    api, model, skeleton, camera, renderer, demos: demos.demos, errors: [], take: null,
    controls: new ViewControls(canvas, renderer, camera),
    player: new Player(model.fps),
    styles: new StylePicker(api, demos.demos, [$("style-select"), $("live-style")], model.builtin_styles || [], model),
  };
  new ResizeObserver(() => renderer.resize()).observe(canvas);
  const transition = new TransitionMode(app), live = new LiveMode(app);
  const modes = { transition, live };
  let mode = "transition";

  function setMode(name) {
    if (modes[mode].deactivate) modes[mode].deactivate();
    mode = name;
    for (const el of document.querySelectorAll("[data-mode]")) {
      if (el.getAttribute("role") === "tab") el.setAttribute("aria-selected", String(el.dataset.mode === name));
      else el.hidden = el.dataset.mode !== name;
    }
    modes[name].activate();
  }
  for (const tab of document.querySelectorAll('[role="tab"]')) tab.addEventListener("click", () => setMode(tab.dataset.mode));

  try {
    await app.styles.refresh();
    const firstTake = app.demos.find((d) => d.kind === "take");
    if (firstTake) await transition.loadDemo(firstTake.name);
    else status("no demo takes: upload a BVH take");
  } catch (err) {
    status(`${err.message}`, "error");
    app.errors.push(err.message);
  }
  setMode(new URLSearchParams(window.location.search).get("mode") === "live" && app.take ? "live" : "transition");

  // Space plays and pauses, unless typing in a field.
  window.addEventListener("keydown", (ev) => {
    if (ev.code === "Space" && mode === "transition" && !/^(INPUT|SELECT|TEXTAREA|BUTTON)$/.test(ev.target.tagName)) {
      ev.preventDefault();
      app.player.toggle();
    }
  });

  let last = performance.now(), renderFps = 0, drawn = 0;
  function loop(now) {
    const dt = Math.min(0.1, (now - last) / 1000);
    last = now;
    renderFps = renderFps * 0.9 + (dt > 0 ? 0.1 / dt : 0);
    if (mode === "transition") app.player.tick(dt);
    renderer.draw(mode === "live" ? live.scene(renderFps) : transition.scene());
    drawn += 1;
    requestAnimationFrame(loop);
  }
  requestAnimationFrame(loop);

  // Read-only views of the state, for the console and the browser tests.
  window.rsmtViewer = {
    ready: true,
    app,
    modes,
    get mode() { return mode; },
    setMode,
    get drawn() { return drawn; },
    errors: app.errors,
    transition: () => ({
      take: app.take ? { name: app.take.name, frames: app.take.motion.frames } : null,
      result: transition.result ? { tracks: transition.result.tracks.map((t) => t.name), frames: transition.result.request.n,
                                    length: app.player.length } : null,
      frame: app.player.frame, playing: app.player.playing, busy: transition.busy, lastExport: transition.lastExport,
    }),
    live: () => live.info(),
    // CSS pixel position of a world point on the canvas, so a test can click a spot on the ground.
    project: (p) => { const q = renderer.project(p); return q ? { x: q[0], y: q[1] } : null; },
  };
}

function sideOf(roles, parents) {
  // Left: a left hip, shoulder or foot and everything below it (parents come before children).
  const side = new Int8Array(parents.length), left = new Set([roles.left_hip, roles.left_shoulder, ...roles.left_foot]);
  for (let j = 0; j < parents.length; j++) if (left.has(j) || (parents[j] >= 0 && side[parents[j]] === -1)) side[j] = -1;
  return side;
}

boot();
