"""Bodies of the viewer's helper routes (``/v1/viewer/...``): uploaded takes, poses, the demo list, the rig."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from service.schemas import ModelName, Motion


class ClipRequest(BaseModel):
    """``POST /v1/viewer/clip``: a take to read onto the model's rig."""

    model_config = ConfigDict(extra="forbid")

    motion: Motion
    name: str = Field("upload", min_length=1, max_length=200, description="shown in the viewer")
    model: ModelName | None = Field(None, description="whose skeleton and fps (default: the default model)")


class ClipPoses(BaseModel):
    """A take as JSON poses on the model's skeleton at its fps (the Motion pose payload, plus a name)."""

    name: str
    fps: float
    frames: int
    root_positions: list[list[float]]
    rotations: list[list[list[float]]]


class DemoInfo(BaseModel):
    name: str
    kind: Literal["take", "style"]
    description: str


class DemoList(BaseModel):
    demos: list[DemoInfo]


class RigRoles(BaseModel):
    root: int
    head: int
    left_hip: int
    right_hip: int
    left_shoulder: int
    right_shoulder: int
    left_foot: list[int]
    right_foot: list[int]
    mirror: list[int] = Field(description="each joint's left/right counterpart (itself on the midline)")


class RigInfo(BaseModel):
    """Joint roles of the model's skeleton, so the viewer measures facing as the model does."""

    model: str
    profile: str
    roles: RigRoles
