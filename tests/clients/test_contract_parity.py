"""Clients that cannot drift: every request field of the contract is written by the Python, Unity and Unreal
clients, or is listed below as one a client leaves out, with the reason.

The contract is the server's own: ``app.openapi()``'s JSON request bodies and the stream's client messages
(:func:`tests.clients.contract_fields.contract_shapes`). A field added to the server fails this test, naming each
client that does not write it and the function to write it in, until the clients send it (or it is listed in
``LEFT_OUT`` with a reason). A listed field that a client now writes, or that the contract no longer has, fails too.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.clients.contract_fields import REPO, braced_keys, contract_shapes, python_keys

PY = REPO / "clients" / "python" / "rsmt_client"
CS = REPO / "clients" / "unity" / "Runtime" / "Core"
CPP = REPO / "clients" / "unreal" / "RsmtLink" / "Source" / "RsmtCore" / "Private"

Builders = list[tuple[Path, str]]
VIEWER_ONLY = "the web viewer's own endpoint (a clip of a demo take); no engine client needs it"
STREAM_ONLY = "transitions go through the stream: a start with pace asap gives a whole transition"

# Where each client builds each request shape: (file, function); a string: the shape is not built, and why.
CLIENTS: dict[str, dict[str, Builders | str]] = {
    "Python": {
        "POST /v1/transition": [(PY / "http_protocol.py", "transition_body"), (PY / "placement.py", "target_field")],
        "POST /v1/styles": [(PY / "http_protocol.py", "register_style"), (PY / "http_protocol.py", "register_style_clips"),
                            (PY / "stream_failover.py", "style_body")],
        "POST /v1/viewer/clip": VIEWER_ONLY,
        "stream start": [(PY / "stream_protocol.py", "StreamSession.start_message"),
                         (PY / "stream_failover.py", "Failover.resume_messages"), (PY / "placement.py", "target_field")],
        "stream retarget": [(PY / "stream_protocol.py", "StreamSession.retarget_message")],
        "stream style": [(PY / "stream_protocol.py", "StreamSession.style_message")],
        "stream cancel": [(PY / "stream_protocol.py", "StreamSession.cancel_message")],
        "stream ping": [(PY / "stream_protocol.py", "StreamSession.ping_message")],
        "BvhMotion": [(PY / "motion.py", "motion_payload")],
        "PoseMotion": [(PY / "motion.py", "Poses.to_payload")],
        "TargetAt": [(PY / "placement.py", "TargetAt.payload")],
    },
    "Unity": {
        "POST /v1/transition": STREAM_ONLY,
        "POST /v1/styles": [(CS / "RsmtHttpClient.cs", "RegisterStyleAsync"),
                            (CS / "RsmtHttpClient.cs", "RegisterStyleClipsAsync")],
        "POST /v1/viewer/clip": VIEWER_ONLY,
        "stream start": [(CS / "RsmtProtocol.cs", "Start")],
        "stream retarget": [(CS / "RsmtProtocol.cs", "Retarget")],
        "stream style": [(CS / "RsmtProtocol.cs", "Style")],
        "stream cancel": [(CS / "RsmtProtocol.cs", "Cancel")],
        "stream ping": [(CS / "RsmtProtocol.cs", "Ping")],
        "BvhMotion": [(CS / "RsmtProtocol.cs", "BvhMotion")],
        "PoseMotion": [(CS / "RsmtProtocol.cs", "PoseMotion")],
        "TargetAt": [(CS / "RsmtProtocol.cs", "TargetAt")],
    },
    "Unreal": {
        "POST /v1/transition": STREAM_ONLY,
        "POST /v1/styles": [(CPP / "RsmtProtocol.cpp", "BuildStyleRegistration")],
        "POST /v1/viewer/clip": VIEWER_ONLY,
        "stream start": [(CPP / "RsmtProtocol.cpp", "BuildStart")],
        "stream retarget": [(CPP / "RsmtProtocol.cpp", "BuildRetarget")],
        "stream style": [(CPP / "RsmtProtocol.cpp", "BuildStyle")],
        "stream cancel": [(CPP / "RsmtProtocol.cpp", "BuildCancel")],
        "stream ping": [(CPP / "RsmtProtocol.cpp", "BuildPing")],
        "BvhMotion": [(CPP / "RsmtProtocol.cpp", "BvhMotionJson")],
        "PoseMotion": [(CPP / "RsmtProtocol.cpp", "PoseMotionJson"), (CPP / "RsmtPoseCapture.cpp", "PoseHistory::MotionJson")],
        "TargetAt": [(CPP / "RsmtProtocol.cpp", "TargetAtJson")],
    },
}

_ECHO_ONLY = "request_id is given to start only: the errors of the other messages name their character"
_DEFAULT_MODEL_STYLES = "styles are registered for the server's default model only (streams name a model in start)"
_STYLE_BY_ID = "a style switch names a registered style (style_id); inline clips go to POST /v1/styles first"
_MODEL_ORDER = "poses are sent in the model's joint order (the recorders and capture map bones to it first)"

# (client, shape, field): why that client does not write the field.
LEFT_OUT: dict[tuple[str, str, str], str] = {
    ("Python", "stream style", "request_id"): _ECHO_ONLY,
    ("Python", "stream cancel", "request_id"): _ECHO_ONLY,
    ("Python", "stream ping", "request_id"): "a ping carries its own id, echoed in the pong",
    **{(client, "stream retarget", "request_id"): _ECHO_ONLY for client in ("Unity", "Unreal")},
    **{(client, "stream style", "request_id"): _ECHO_ONLY for client in ("Unity", "Unreal")},
    **{(client, "stream cancel", "request_id"): _ECHO_ONLY for client in ("Unity", "Unreal")},
    **{(client, "stream ping", "request_id"): "a ping carries its own id, echoed in the pong" for client in ("Unity", "Unreal")},
    **{(client, "stream style", "style"): _STYLE_BY_ID for client in ("Unity", "Unreal")},
    **{(client, "POST /v1/styles", "model"): _DEFAULT_MODEL_STYLES for client in ("Unity", "Unreal")},
    **{(client, "PoseMotion", "joints"): _MODEL_ORDER for client in ("Unity", "Unreal")},
    ("Unreal", "POST /v1/styles", "motion"): "one clip is sent as motions: [clip], which the contract takes alike",
}


def written(builders: Builders) -> set[str]:
    keys: set[str] = set()
    for path, function in builders:
        keys |= python_keys(path, function) if path.suffix == ".py" else braced_keys(path, function)
    return keys


@pytest.fixture(scope="module")
def contract() -> dict[str, set[str]]:
    return contract_shapes()


def test_the_contract_is_read_whole(contract):
    """The shapes come from the server: both HTTP bodies, the five stream messages and the two Motion forms."""
    assert {"POST /v1/transition", "POST /v1/styles", "stream start", "stream retarget", "stream style",
            "stream cancel", "stream ping", "BvhMotion", "PoseMotion"} <= set(contract)
    assert {"context", "target", "frames", "style_strength", "exact_arrival"} <= contract["POST /v1/transition"]
    assert {"type", "pace", "style_strength", "retargeted", "target_at"} <= contract["stream start"]
    assert contract["TargetAt"] == {"x", "z", "yaw"}


def test_every_client_names_every_shape(contract):
    for client, shapes in CLIENTS.items():
        assert set(shapes) == set(contract), (
            f"{client}: shapes of the contract not placed in CLIENTS: {sorted(set(contract) - set(shapes))}; "
            f"placed but gone from the contract: {sorted(set(shapes) - set(contract))}")


def test_every_request_field_reaches_every_client(contract):
    missing, stale = [], []
    for client, shapes in CLIENTS.items():
        for shape, builders in shapes.items():
            if isinstance(builders, str) or shape not in contract:
                continue
            keys = written(builders)
            where = ", ".join(f"{function} ({path.relative_to(REPO)})" for path, function in builders)
            for field in sorted(contract[shape]):
                left_out = (client, shape, field) in LEFT_OUT
                if field not in keys and not left_out:
                    missing.append(f"the {client} client does not send `{field}` of {shape}: write it in {where}")
                elif field in keys and left_out:
                    stale.append(f"the {client} client now sends `{field}` of {shape}: drop it from LEFT_OUT")
    for (client, shape, field) in LEFT_OUT:
        if field not in contract.get(shape, set()):
            stale.append(f"LEFT_OUT lists `{field}` of {shape} for {client}, which the contract no longer has")
    assert not missing and not stale, "\n".join(missing + stale)
