"""The viewer in a real browser: headless chromium (Debian's) driven through chromedriver, against a real
server on 127.0.0.1 with a random-weight bundle. Skipped with the reason where chromium is absent.

The page exposes ``window.rsmtViewer`` (read-only views of its state); the tests wait on it, click real
buttons, press and drag on the canvas with real pointer events, and compare canvas screenshots.
"""

from __future__ import annotations

import io
import math
import re
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from model.data.synthetic import synthetic_walk
from model.evaluation.baselines import interpolate
from model.motion.bvh_clip import dump_clip
from tests.viewer.conftest import README_SCREENSHOT, UPDATE_SCREENSHOTS

pytestmark = pytest.mark.slow

V = "window.rsmtViewer"


def open_viewer(browser, server, query: str = "") -> None:
    browser.get(f"{server.url}/viewer/{query}")
    browser.wait_for(f"{V} && {V}.ready && {V}.transition().take", 60, "the viewer to load its first take")


def pixels(png: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)


def changed_fraction(a: bytes, b: bytes) -> float:
    return float((np.abs(pixels(a) - pixels(b)).sum(-1) > 30).mean())


def colour_pixels(png: bytes, rgb: tuple[int, int, int], tol: int = 40) -> int:
    return int((np.abs(pixels(png) - np.array(rgb)).max(-1) < tol).sum())


def save(png: bytes, path: Path) -> Path:
    # A palette of 128 colours: the flat colours of the page survive, and the file stays small for the README.
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.open(io.BytesIO(png)).convert("RGB").quantize(colors=128, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)
    return path


def test_the_page_loads_and_draws_the_skeleton_on_a_grid(browser, viewer_server) -> None:
    open_viewer(browser, viewer_server)
    info = browser.execute("return document.getElementById('model-info').textContent")
    assert "21 joints" in info and "30 fps" in info, info
    assert browser.execute(f"return {V}.errors") == []
    shot = browser.screenshot("#view")
    assert colour_pixels(shot, (0xC9, 0xD1, 0xDC)) > 200  # the take's skeleton, in its colour
    assert colour_pixels(shot, (0x15, 0x18, 0x1D), tol=3) > 0  # the background between grid lines
    assert len(np.unique(pixels(shot).reshape(-1, 3), axis=0)) > 50  # grid, shadows, labels: not a blank canvas


def test_drag_orbits_and_the_wheel_zooms(browser, viewer_server) -> None:
    open_viewer(browser, viewer_server)
    cam = f"{V}.app.camera"
    before = browser.execute(f"return {{yaw: {cam}.yaw, pitch: {cam}.pitch, distance: {cam}.distance}}")
    browser.drag("#view", (300, 300), (420, 260))
    browser.scroll("#view", 400)
    after = browser.execute(f"return {{yaw: {cam}.yaw, pitch: {cam}.pitch, distance: {cam}.distance}}")
    assert after["yaw"] != pytest.approx(before["yaw"]) and after["pitch"] != pytest.approx(before["pitch"])
    assert after["distance"] > before["distance"] * 1.2  # wheel down: further away


def test_the_pages_kinematics_and_baseline_match_the_models(browser, viewer_server) -> None:
    # The JS does its own forward kinematics and interpolation baseline: they must agree with model/.
    open_viewer(browser, viewer_server)
    got = browser.execute_async("""
        const done = arguments[arguments.length - 1];
        import("./js/math.js").then((M) => {
          const app = window.rsmtViewer.app, m = app.take.motion, sk = app.skeleton;
          const fk = [0, 37, 120].map((f) => {
            const p = M.poseAt(m, f);
            return Array.from(M.forwardKinematics(sk, p.root, p.rots));
          });
          const base = M.interpolateBaseline(M.poseAt(m, 60), M.poseAt(m, 90), 30);
          const placed = M.placeMotion(sk, M.sliceMotion(m, 89, 91), [150, 0, -80], 1.0);
          const last = M.poseAt(placed, 1), pos = M.forwardKinematics(sk, last.root, last.rots);
          done({fk, baseRoots: Array.from(base.roots), baseRots: Array.from(base.rots), placedRoot: last.root,
                placedYaw: M.facingYaw(sk, pos, Array.from(last.rots.subarray(0, 4)))});
        }).catch((e) => done({error: String(e)}));
    """)
    assert "error" not in got, got
    walk = synthetic_walk(240)  # the demo take "walk", made the same way on the server
    positions = walk.global_positions().numpy()
    for i, f in enumerate((0, 37, 120)):
        assert np.allclose(np.reshape(got["fk"][i], (-1, 3)), positions[f], atol=1e-2), f
    rot, root = interpolate(walk.rotations[60:61], walk.root_positions[60:61],
                            walk.rotations[90:91], walk.root_positions[90:91], 30)
    assert np.allclose(np.reshape(got["baseRoots"], (30, 3)), root[0].numpy(), atol=1e-3)
    ours = np.reshape(got["baseRots"], (30, -1, 4))
    assert np.all(np.abs((ours * rot[0].numpy()).sum(-1)) > 1 - 1e-4)
    assert got["placedRoot"][0] == pytest.approx(150, abs=1e-3) and got["placedRoot"][2] == pytest.approx(-80, abs=1e-3)
    assert math.remainder(got["placedYaw"] - 1.0, 2 * math.pi) == pytest.approx(0, abs=1e-3)


def test_a_transition_is_generated_plays_and_exports(browser, viewer_server, artefacts) -> None:
    open_viewer(browser, viewer_server)
    browser.click("#generate")  # the default style is a demo clip, registered on first use
    result = browser.wait_for(f"{V}.transition().result", 90, "the transition")
    n = result["frames"]
    assert result["tracks"] == ["RSMT", "interpolation", "ground truth"]
    assert browser.wait_for(f"{V}.transition().playing", 5)
    first, f0 = browser.screenshot("#view"), browser.execute(f"return {V}.transition().frame")
    time.sleep(0.5)
    second, f1 = browser.screenshot("#view"), browser.execute(f"return {V}.transition().frame")
    assert f1 != f0, "the timeline did not advance"
    assert changed_fraction(first, second) > 0.001, "the canvas did not change while playing"
    for colour in ((0x4D, 0xA3, 0xFF), (0xF2, 0xA9, 0x3B), (0x5F, 0xD3, 0x8D)):  # model, baseline, ground truth
        assert colour_pixels(second, colour) > 50, colour

    browser.click("#export")
    export = browser.wait_for(f"{V}.transition().lastExport", 60, "the BVH export")
    assert export["frames"] == n and export["bytes"] > 1000

    # Pause mid-transition for the picture: the three side by side, the target ghosts and the trails.
    browser.click("#play")
    browser.execute("const s = document.getElementById('scrub'); s.value = arguments[0]; s.dispatchEvent(new Event('input'));",
                    result["length"] - n // 2)
    time.sleep(0.6)  # let the camera settle on the paused frame
    shot = browser.screenshot()
    save(shot, artefacts / "viewer-transition.png")
    if UPDATE_SCREENSHOTS:
        assert save(shot, README_SCREENSHOT).stat().st_size < 300_000
    assert browser.execute(f"return {V}.errors") == []


def test_a_target_placed_on_the_ground(browser, viewer_server) -> None:
    open_viewer(browser, viewer_server)
    browser.click('input[name="target-kind"][value="ground"]')
    browser.click("#place-target")
    # Press where the world point (120, 0, 300) is drawn and drag towards +X: target there, facing +X.
    a = browser.execute(f"return {V}.project([120, 0, 300])")
    b = browser.execute(f"return {V}.project([220, 0, 300])")
    browser.drag("#view", (a["x"], a["y"]), (b["x"], b["y"]))
    browser.wait_for("document.getElementById('status').textContent.startsWith('target placed')", 5)
    browser.click("#generate")
    result = browser.wait_for(f"{V}.transition().result", 90, "the transition")
    assert result["tracks"] == ["RSMT", "interpolation"]  # no ground truth for a target off the take
    target = browser.execute(f"""
        const r = {V}.modes.transition.result.request.targetMotion, f = r.frames - 1;
        return {{root: Array.from(r.roots.subarray(f * 3, f * 3 + 3)), ground: {V}.modes.transition.ground}};""")
    assert target["root"][0] == pytest.approx(target["ground"]["point"][0], abs=1e-3)
    assert target["ground"]["point"][0] == pytest.approx(120, abs=3) and target["ground"]["point"][2] == pytest.approx(300, abs=3)
    assert target["ground"]["yaw"] == pytest.approx(math.pi / 2, abs=0.05)


def test_an_uploaded_take_and_style(browser, viewer_server, tmp_path) -> None:
    take = tmp_path / "turning.bvh"
    take.write_text(dump_clip(synthetic_walk(150, fps=60.0, turn_deg_s=-30.0), rotation_order="XYZ"))
    style = tmp_path / "bouncy-upload.bvh"
    style.write_text(dump_clip(synthetic_walk(60, cadence_hz=1.4, stride_deg=35.0)))
    open_viewer(browser, viewer_server)
    browser.send_keys("#take-file", str(take))
    got = browser.wait_for(f"{V}.transition().take.name === 'turning.bvh' && {V}.transition().take", 30, "the uploaded take")
    assert got["frames"] == 75  # 150 frames at 60 fps, read at the model's 30
    browser.send_keys("#style-file", str(style))
    browser.wait_for("document.getElementById('style-select').selectedOptions[0].text.startsWith('bouncy-upload')", 30,
                     "the uploaded style to be registered and chosen")
    browser.click("#generate")
    assert browser.wait_for(f"{V}.transition().result", 90, "the transition")["tracks"][0] == "RSMT"
    assert browser.execute(f"return {V}.errors") == []


def test_a_long_style_clip_is_cut_as_the_clients_cut_it_and_the_page_says_so(browser, viewer_server, tmp_path) -> None:
    """Issue 64: the viewer refused a 289-frame style upload where the clients send its middle frames."""
    most = browser_model_max(browser, viewer_server)
    style = tmp_path / "long-style.bvh"
    style.write_text(dump_clip(synthetic_walk(400, cadence_hz=1.2)))
    browser.send_keys("#style-file", str(style))
    browser.wait_for("document.getElementById('style-select').selectedOptions[0].text.startsWith('long-style')", 60,
                     "the long style to be registered (cut) and chosen")
    page = browser.execute("return {status: document.getElementById('status').textContent, "
                           "note: document.getElementById('style-note').textContent, "
                           "option: document.getElementById('style-select').selectedOptions[0].text}")
    start = (400 - most) // 2
    assert page["note"] == f"style long-style: cut to the middle {most} of 400 frames", page
    assert f"its middle {most} (frames {start}-{start + most - 1}) were sent" in page["status"], page
    assert page["option"] == f"long-style ({most} frames)", page
    browser.click("#generate")
    assert browser.wait_for(f"{V}.transition().result", 90, "the transition")["tracks"][0] == "RSMT"
    assert browser.execute(f"return {V}.errors") == []


def test_a_failed_style_upload_leaves_no_style_chosen(browser, viewer_server, tmp_path) -> None:
    """Issue 64: after a refused upload, Generate quietly used the style chosen before."""
    open_viewer(browser, viewer_server)
    browser.click("#generate")  # a first result, with the style chosen at load
    browser.wait_for(f"{V}.transition().result", 90, "the first transition")
    browser.execute(f"window.firstResult = {V}.modes.transition.result")
    broken = tmp_path / "broken-style.bvh"
    broken.write_text(re.sub(r"Frame Time: .*", "Frame Time: 1e-310", dump_clip(synthetic_walk(60))))
    browser.send_keys("#style-file", str(broken))
    browser.wait_for("document.getElementById('status').className === 'error'", 30, "the upload's error")
    page = browser.execute("return {status: document.getElementById('status').textContent, "
                           "note: document.getElementById('style-note').textContent, "
                           "value: document.getElementById('style-select').value, "
                           "option: document.getElementById('style-select').selectedOptions[0].text}")
    assert page["status"].startswith("style broken-style.bvh was not registered: ") and "Frame Time" in page["status"], page
    assert page["note"] == page["status"] and page["value"] == "", page
    assert page["option"] == "broken-style.bvh: not registered (see the error)", page
    browser.click("#generate")
    browser.wait_for("document.getElementById('status').textContent.startsWith('pick a style')", 30,
                     "Generate to ask for a style")
    assert browser.execute(f"return {V}.modes.transition.result === window.firstResult")  # nothing generated since


def browser_model_max(browser, server) -> int:
    """The viewer open on ``server``, and the most style frames its model reads."""
    open_viewer(browser, server)
    return int(browser.execute(f"return {V}.app.model.style_clip_frames.max"))


def test_live_mode_streams_frames_and_follows_clicks(browser, viewer_server, artefacts) -> None:
    open_viewer(browser, viewer_server)
    browser.click("#tab-live")
    browser.click("#live-start")
    live = browser.wait_for(f"{V}.live().frames > 10 && {V}.live()", 30, "streamed frames")
    assert live["connected"] and live["character"]
    first = browser.screenshot("#view")
    # A click on the ground while it walks: retarget mid-motion, frames keep coming.
    p = browser.execute(f"const r = {V}.app.take; return {V}.project([-150, 0, 250])")
    browser.click_at("#view", p["x"], p["y"])
    browser.wait_for(f"{V}.live().retargets === 1", 10, "the retarget")
    before = browser.execute(f"return {V}.live().frames")
    browser.wait_for(f"{V}.live().frames > {before + 10}", 15, "frames after the retarget")
    # Another style, on the fly.
    browser.click("#live-style option:nth-child(2)")
    browser.wait_for(f"{V}.live().styleChanges >= 1", 30, "the style switch")
    live = browser.execute(f"return {V}.live()")
    assert live["fps"] > 5 and live["latenessMs"] is not None and live["rttMs"] is not None
    hud = browser.execute("return document.getElementById('hud').textContent")
    assert "fps" in hud and "latency" in hud
    second = browser.screenshot("#view")
    assert changed_fraction(first, second) > 0.001
    save(browser.screenshot(), artefacts / "viewer-live.png")
    browser.click("#live-stop")
    assert browser.execute(f"return {V}.errors") == []
