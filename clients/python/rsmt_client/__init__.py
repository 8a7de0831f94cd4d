"""Python client of the RSMT motion transition service (HTTP and WebSocket ``/v1/stream``).

    from rsmt_client import Client, StreamClient

    with Client("http://127.0.0.1:8000") as c:
        style = c.register_style("proud.bvh")["style_id"]
        poses = c.transition("context.bvh", "target.bvh", frames=40, style_id=style, seed=7)
        poses.save_bvh("out.bvh", c.model())          # or poses.root_positions / poses.rotations

    with StreamClient("http://127.0.0.1:8000", encoding="binary") as s:
        hero = s.start("context.bvh", "target.bvh", 40, style_id=style)
        for_hero = s.collect(hero)                     # frames as numpy arrays, then the end message

Everything is in the model's units and axes (``GET /v1/model``: cm, Y up, right-handed,
quaternions x, y, z, w). BVH files are read and written here with numpy alone (:mod:`rsmt_client.bvh`):
the client needs numpy, httpx and websockets, no torch. See clients/python/README.md.

The names below load their module on first use, so ``from rsmt_client import Client`` does not import numpy
or websockets (a command such as ``rsmt client styles list`` starts faster).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from rsmt_client._retry import NO_RETRY, RetryPolicy, parse_retry_after
    from rsmt_client.bvh import BvhError
    from rsmt_client.errors import RsmtError
    from rsmt_client.frames import Frame, FrameLayout
    from rsmt_client.http import AsyncClient, Client
    from rsmt_client.http_protocol import DEFAULT_URL
    from rsmt_client.motion import Poses, load_bvh_poses, motion_payload, poses_to_bvh, read_bvh
    from rsmt_client.placement import TargetAt
    from rsmt_client.reach import Reach
    from rsmt_client.stream import AsyncStreamClient, StreamClient
    from rsmt_client.stream_protocol import StreamResult, stream_url

_MODULES = {
    "rsmt_client._retry": ("NO_RETRY", "RetryPolicy", "parse_retry_after"),
    "rsmt_client.bvh": ("BvhError",),
    "rsmt_client.errors": ("RsmtError",),
    "rsmt_client.frames": ("Frame", "FrameLayout"),
    "rsmt_client.http": ("AsyncClient", "Client"),
    "rsmt_client.http_protocol": ("DEFAULT_URL",),
    "rsmt_client.motion": ("Poses", "load_bvh_poses", "motion_payload", "poses_to_bvh", "read_bvh"),
    "rsmt_client.placement": ("TargetAt",),
    "rsmt_client.reach": ("Reach",),
    "rsmt_client.stream": ("AsyncStreamClient", "StreamClient"),
    "rsmt_client.stream_protocol": ("StreamResult", "stream_url"),
}
_WHERE = {name: module for module, names in _MODULES.items() for name in names}

__all__ = [
    "DEFAULT_URL", "NO_RETRY", "AsyncClient", "AsyncStreamClient", "BvhError", "Client", "Frame", "FrameLayout", "Poses",
    "Reach", "RetryPolicy", "RsmtError", "StreamClient", "StreamResult", "TargetAt", "load_bvh_poses", "motion_payload",
    "parse_retry_after", "poses_to_bvh", "read_bvh", "stream_url",
]
__version__ = "0.1.0"


def __getattr__(name: str) -> Any:
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module 'rsmt_client' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
