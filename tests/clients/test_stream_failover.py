"""The stream client's failover (rsmt_client.stream_failover, issue 26 item 3): the sans-I/O core on
hand-made traffic (what is resent after a lost connection, how resumed frames are numbered, styles
registered again on ``unknown_style``), and the re-registration against a real server, sync and async.
The resume across a killed replica behind HAProxy is tests/service/test_replicas.py."""

from __future__ import annotations

import asyncio
from typing import Any

import numpy as np
import pytest
from rsmt_client import AsyncStreamClient, Client, StreamClient
from rsmt_client.frames import Frame
from rsmt_client.stream_failover import Failover, http_url, style_body

from tests.clients.helpers import API_KEY

J, CTX, FPS = 3, 4, 30.0
NAMES = ("hips", "spine", "head")


def frame(character: str, seq: int, remaining: int, value: float = 0.0) -> Frame:
    return Frame(character, 0, seq, (seq + 1) / FPS, remaining, np.full(3, value, np.float32),
                 np.tile(np.array([0, 0, 0, 1], np.float32), (J, 1)))


def as_message(item: Frame | dict[str, Any] | None) -> dict[str, Any]:
    """An item handed to the caller that the test expects to be a message (not a frame, not swallowed)."""
    assert isinstance(item, dict), item
    return item


def as_frame(item: Frame | dict[str, Any] | None) -> Frame:
    """An item handed to the caller that the test expects to be a frame."""
    assert isinstance(item, Frame), item
    return item


def start(character: str = "hero", frames: int = 10, **kw) -> dict:
    context = {"root_positions": [[float(i), 0.0, 0.0] for i in range(6)],
               "rotations": [[[0.0, 0.0, 0.0, 1.0]] * J for _ in range(6)]}
    msg = {"type": "start", "character": character, "context": context, "target": {"bvh": "T"}, "frames": frames,
           "style_id": "sty_a", "pace": "realtime", "deterministic": False}
    msg.update(kw)
    return msg


def test_resume_from_the_last_frames_received_and_number_on():
    f = Failover(CTX, FPS, NAMES)
    f.sent(start(frames=10))
    assert as_message(f.received({"type": "started", "character": "hero", "slot": 0}).item)["type"] == "started"
    for seq in range(6):
        assert as_frame(f.received(frame("hero", seq, 9 - seq, value=100.0 + seq)).item).seq == seq
    (msg,) = f.resume_messages()
    assert msg["frames"] == 4 and msg["target"] == {"bvh": "T"} and msg["style_id"] == "sty_a"
    assert [r[0] for r in msg["context"]["root_positions"]] == [102.0, 103.0, 104.0, 105.0]  # the last CTX received
    assert f.resumes == 1
    assert as_message(f.received({"type": "started", "character": "hero", "slot": 1}).item)["resumed"] is True
    out = [as_frame(f.received(frame("hero", seq, 3 - seq)).item) for seq in range(4)]
    assert [x.seq for x in out] == [6, 7, 8, 9] and out[-1].t == pytest.approx(10 / FPS)
    assert as_message(f.received({"type": "end", "character": "hero", "frames": 4}).item)["frames"] == 10
    assert not f.live and f.resume_messages() == []


def test_few_frames_received_take_the_original_context_before_them():
    f = Failover(CTX, FPS, NAMES)
    f.sent(start(frames=10))
    f.received(frame("hero", 0, 9, value=50.0))
    (msg,) = f.resume_messages()
    assert [r[0] for r in msg["context"]["root_positions"]] == [3.0, 4.0, 5.0, 50.0]
    g = Failover(CTX, FPS, NAMES)  # a context this client cannot read: the first received pose is held
    g.sent(start(frames=10, context={"bvh": "not a bvh"}))
    g.received(frame("hero", 0, 9, value=50.0))
    assert [r[0] for r in g.resume_messages()[0]["context"]["root_positions"]] == [50.0] * 4


def test_nothing_received_yet_resends_the_start_and_cancelled_characters_stay_gone():
    f = Failover(CTX, FPS, NAMES)
    f.sent(start("a", frames=10))
    f.sent(start("b", frames=10))
    f.sent({"type": "cancel", "character": "b"})
    (msg,) = f.resume_messages()
    assert msg == start("a", frames=10)


def test_retarget_and_style_are_carried_into_the_resume():
    f = Failover(CTX, FPS, NAMES)
    f.sent(start(frames=10))
    for seq in range(5):
        f.received(frame("hero", seq, 9 - seq))
    f.sent({"type": "retarget", "character": "hero", "target": {"bvh": "T2"}, "frames": 20})
    f.sent({"type": "style", "character": "hero", "style": {"bvh": "S"}})
    (msg,) = f.resume_messages()
    assert msg["frames"] == 20 and msg["target"] == {"bvh": "T2"} and msg["style"] == {"bvh": "S"}
    assert "style_id" not in msg and msg["retargeted"] is True  # its facing finishes as a retargeted one's
    g = Failover(CTX, FPS, NAMES)  # once a frame after the retarget has come, its remaining counts
    g.sent(start(frames=10))
    g.received(frame("hero", 0, 9))
    g.sent({"type": "retarget", "character": "hero", "frames": 20})
    g.received({"type": "retargeted", "character": "hero", "from_seq": 1})
    g.received(frame("hero", 1, 19))
    (resumed,) = g.resume_messages()
    assert resumed["frames"] == 19 and "retargeted" not in resumed  # a new duration alone is no new target


def _resumed_after_a_retarget() -> tuple[Failover, dict]:
    """A failover whose character was retargeted mid-motion, and the resume it sends after a drop."""
    f = Failover(CTX, FPS, NAMES)
    f.sent(start(frames=10))
    f.received(frame("hero", 0, 9))
    f.sent({"type": "retarget", "character": "hero", "target": {"bvh": "T2"}})
    (resume,) = f.resume_messages()
    return f, resume


def test_a_resume_refused_for_its_retargeted_option_is_sent_again_without_it():
    f, resume = _resumed_after_a_retarget()  # an older replica (a rolling upgrade) does not know the option
    assert resume["retargeted"] is True
    act = f.received({"type": "error", "character": "hero", "code": "validation_error"})
    assert act.item is None and act.register is None
    (again,) = act.send
    assert again == {k: v for k, v in resume.items() if k != "retargeted"}
    assert as_message(f.received({"type": "started", "character": "hero"}).item)["resumed"] is True
    g, _ = _resumed_after_a_retarget()  # refused again (or a plain start refused): the error reaches the caller
    g.received({"type": "error", "character": "hero", "code": "validation_error"})
    last = g.received({"type": "error", "character": "hero", "code": "validation_error"})
    assert isinstance(last.item, dict) and last.item["code"] == "validation_error" and not last.send and not g.live


def test_a_target_changed_before_any_frame_resumes_as_a_start_to_it_not_a_retarget():
    f = Failover(CTX, FPS, NAMES)
    f.sent(start(frames=10))
    f.sent({"type": "retarget", "character": "hero", "target": {"bvh": "T2"}})
    (msg,) = f.resume_messages()
    assert msg == start(frames=10, target={"bvh": "T2"})


def test_unknown_style_registers_the_clip_again_and_resends():
    f = Failover(CTX, FPS, NAMES)
    body = {"name": "walk", "motion": {"bvh": "S"}}
    f.remember_style("sty_a", body)
    f.sent(start())
    act = f.received({"type": "error", "character": "hero", "code": "unknown_style", "message": "m"})
    assert act.item is None and act.register == ("sty_a", body) and act.send == [start()]
    f.received({"type": "started", "character": "hero"})
    f.sent({"type": "style", "character": "hero", "style_id": "sty_a"})
    act = f.received({"type": "error", "character": "hero", "code": "unknown_style", "message": "m"})
    assert act.send == [{"type": "style", "character": "hero", "style_id": "sty_a"}]
    g = Failover(CTX, FPS, NAMES)  # a style it never held: the caller gets the error, nothing is resumed
    g.sent(start())
    err = {"type": "error", "character": "hero", "code": "unknown_style", "message": "m"}
    assert g.received(err).item == err and not g.live


def test_unknown_style_during_a_resume_resends_the_resume_not_the_original_start():
    f = Failover(CTX, FPS, NAMES)
    f.remember_style("sty_a", {"name": "walk", "motion": {"bvh": "S"}})
    f.sent(start(frames=10))
    f.received({"type": "started", "character": "hero"})
    for seq in range(6):
        f.received(frame("hero", seq, 9 - seq, value=100.0 + seq))
    (resume,) = f.resume_messages()
    # the new replica does not know the style: register it, then resend what was refused, the resume
    act = f.received({"type": "error", "character": "hero", "code": "unknown_style", "message": "m"})
    assert act.register is not None and act.send == [resume]
    assert act.send[0]["frames"] == 4 and act.send[0]["context"] != start()["context"]
    f.received({"type": "started", "character": "hero"})
    assert [as_frame(f.received(frame("hero", s, 3 - s)).item).seq for s in range(4)] == [6, 7, 8, 9]


def test_a_style_body_holds_one_clip_as_motion_and_several_as_motions():
    one = {"bvh": "HIERARCHY one"}
    assert style_body([one], "walk", None) == {"name": "walk", "motion": one}
    both = style_body([one, {"bvh": "HIERARCHY two"}], None, "m")
    assert both == {"name": "style", "motions": [one, {"bvh": "HIERARCHY two"}], "model": "m"}
    for clips in ([], [one] * 6):
        with pytest.raises(ValueError, match=f"1 to 5 clips; got {len(clips)}"):
            style_body(clips, None, None)


def test_http_url():
    assert http_url("ws://lb:8000/v1/stream?encoding=binary&token=k") == "http://lb:8000"
    assert http_url("wss://h/prefix/v1/stream?encoding=json") == "https://h/prefix"


# ---------------------------------------------------------------------- against a real server

def test_sync_stream_registers_a_deleted_style_again(server, motions):
    with StreamClient(server.url, api_key=API_KEY, failover=True) as s:
        sid = s.register_style(motions["style"], name="walk")
        with Client(server.url, api_key=API_KEY) as c:
            c.delete_style(sid)
        poses = s.transition(motions["context"], motions["target"], 12, style_id=sid, seed=1)
        assert poses.num_frames == 12 and poses.style_id == sid
    with Client(server.url, api_key=API_KEY) as c:
        assert sid in {x["style_id"] for x in c.styles()}


def test_async_stream_registers_a_deleted_style_again(server, motions):
    async def run() -> int:
        s = await AsyncStreamClient.connect(server.url, api_key=API_KEY, failover=True)
        async with s:
            sid = await s.register_style(motions["style2"], name="walk2")
            with Client(server.url, api_key=API_KEY) as c:
                c.delete_style(sid)
            return (await s.transition(motions["context"], motions["target"], 12, style_id=sid, seed=1)).num_frames

    assert asyncio.run(run()) == 12


def test_a_style_of_several_clips_is_registered_again_from_all_of_them(server, motions):
    with StreamClient(server.url, api_key=API_KEY, failover=True) as s:
        sid = s.register_style_clips([motions["style"], motions["style2"]], name="both")
        with Client(server.url, api_key=API_KEY) as c:
            assert c.style(sid)["clips"] == 2
            c.delete_style(sid)
        poses = s.transition(motions["context"], motions["target"], 12, style_id=sid, seed=1)
        assert poses.num_frames == 12 and poses.style_id == sid
    with Client(server.url, api_key=API_KEY) as c:
        assert c.style(sid)["clips"] == 2  # both clips again, under the same id

    async def run() -> tuple[str, int]:
        s = await AsyncStreamClient.connect(server.url, api_key=API_KEY, failover=True)
        async with s:
            again = await s.register_style_clips([motions["style2"], motions["style"]])
            with Client(server.url, api_key=API_KEY) as c:
                c.delete_style(again)
            return again, (await s.transition(motions["context"], motions["target"], 12, style_id=again,
                                              seed=1)).num_frames

    assert asyncio.run(run()) == (sid, 12)


def test_a_bvh_context_on_the_models_rig_is_read_for_the_resume():
    from model.data.synthetic import synthetic_skeleton, synthetic_walk
    from model.motion.bvh_clip import dump_clip

    clip = synthetic_walk(20)
    names = tuple(synthetic_skeleton().names)
    f = Failover(CTX, float(clip.fps), names)
    f.sent(start(frames=10, context={"bvh": dump_clip(clip)}))
    f.received(Frame("hero", 0, 0, 1 / clip.fps, 9, np.zeros(3, np.float32),
                     np.tile(np.array([0, 0, 0, 1], np.float32), (len(names), 1))))
    roots = np.array(f.resume_messages()[0]["context"]["root_positions"])
    assert np.allclose(roots[:3], clip.root_positions.numpy()[-3:], atol=1e-3) and np.allclose(roots[3], 0)
