"""Request and response bodies of the contract (HTTP and WebSocket), with their validation and examples.

Shapes that depend on the loaded model (joint count, frame limits) are checked when a Motion is
converted (:mod:`service.motion`); here sit the limits that hold for any model.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictFloat, StrictInt, TypeAdapter, model_validator

from service.request_controls import RequestControls

# Hard ceilings for any model; the configured limits (service.settings) are usually lower.
MAX_FRAMES_ANY = 100_000
MAX_JOINTS_ANY = 1_000
# A built-in style's id is this prefix and its name (docs/api-contract.md); the styles package serves them, error
# hints below it name them.
BUILTIN_PREFIX = "builtin:"
# The largest integer a JSON number holds exactly in JavaScript (Number.MAX_SAFE_INTEGER).
SEED_MAX = 2**53 - 1

# Numbers are JSON numbers and counts JSON integers: "30", 30.0, true and "0.5" are refused (strict types; a
# bool is not an int), rather than read as 30, 30, 1 and 0.5.
Vec3 = Annotated[list[StrictFloat], Field(min_length=3, max_length=3)]
Quat = Annotated[list[StrictFloat], Field(min_length=4, max_length=4, description="x, y, z, w")]
# A transition's frames: a JSON integer here; its range is decided in one place, the engine's check
# (Engine.check_frames: 1 to the model's longest, RSMT_MAX_TRANSITION_FRAMES capping it), whose error names the model
# and the range. The schema only tells clients the lower bound (``minimum`` in the OpenAPI contract) and checks nothing.
FrameCount = Annotated[StrictInt, Field(json_schema_extra={"minimum": 1})]
Seed = Annotated[StrictInt, Field(ge=0, le=SEED_MAX, description="sampling seed, at most 2^53 - 1 (default: random)")]
CharacterId = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.:\-]+$")]
StyleId = Annotated[str, Field(min_length=1, max_length=128)]
ModelName = Annotated[str, Field(min_length=1, max_length=128)]
RequestId = Annotated[str | int | None, Field(None, description="echoed in any error this message causes")]

_EXAMPLE_BVH = """HIERARCHY
ROOT Hips
{
\tOFFSET 0 0 0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
\tJOINT Spine
\t{
\t\tOFFSET 0 10 0
\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 10 0
\t\t}
\t}
}
MOTION
Frames: 2
Frame Time: 0.0333333
0 92 0 0 0 0 0 0 0
0 92 4 0 0 0 0 0 0
"""


class BvhMotion(BaseModel):
    """Motion as BVH text: joints are matched to the model's skeleton by name, any channel order, any frame time."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [{"bvh": _EXAMPLE_BVH}]})

    bvh: str = Field(min_length=1, description="BVH text (HIERARCHY ... MOTION ...)")


class PoseMotion(BaseModel):
    """Motion as arrays: root positions and local x,y,z,w quaternions, joints in the order of ``skeleton.joints``."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"root_positions": [[0.0, 92.0, 0.0]], "rotations": [[[0.0, 0.0, 0.0, 1.0]]],
                                          "joints": ["Hips"]}]},
    )

    root_positions: list[Vec3] = Field(min_length=1, max_length=MAX_FRAMES_ANY, description="[frames][3], model units")
    rotations: list[Annotated[list[Quat], Field(min_length=1, max_length=MAX_JOINTS_ANY)]] = Field(
        min_length=1, max_length=MAX_FRAMES_ANY, description="[frames][joints][4] local unit quaternions x,y,z,w"
    )
    joints: list[Annotated[str, Field(min_length=1, max_length=256)]] | None = Field(
        None, max_length=MAX_JOINTS_ANY, description="joint names of the rotation columns, when not the model's order"
    )
    fps: StrictFloat | None = Field(None, gt=0, le=1000, description="frame rate of these frames (default: the model's fps)")


Motion = Annotated[BvhMotion | PoseMotion, Field(description="BVH text or JSON poses")]
# The most clips one style is registered from (the engine's own bound: model.inference.style_sets.MAX_STYLE_CLIPS).
MAX_STYLE_CLIPS = 5


class _StyleChoice(BaseModel):
    style_id: StyleId | None = Field(None, description="an id from POST /v1/styles, or builtin:NAME (GET /v1/styles)")
    style: Motion | None = Field(None, description="a style clip, encoded (and cached) on the fly")

    @model_validator(mode="after")
    def _one_style(self) -> Any:
        if (self.style_id is None) == (self.style is None):
            raise ValueError("give exactly one of style_id or style")
        return self


PLACE_MAX = 1e6  # the largest |x| or |z| of a target_at, in model units


class TargetAt(BaseModel):
    """A target given as a place and a facing; the engine picks the pose (the context's last one, turned and moved)."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [{"x": 120.0, "z": 300.0, "yaw": 90.0}]})

    x: StrictFloat = Field(ge=-PLACE_MAX, le=PLACE_MAX, allow_inf_nan=False,
                           description="where the root arrives along +X, model units (the model's skeleton.units)")
    z: StrictFloat = Field(ge=-PLACE_MAX, le=PLACE_MAX, allow_inf_nan=False,
                           description="where the root arrives along +Z, model units")
    yaw: StrictFloat = Field(ge=-360, le=360, allow_inf_nan=False,
                             description="the facing to arrive with, degrees about +Y (up): 0 faces +Z, 90 faces +X")


class _TargetChoice(BaseModel):
    target: Motion | None = Field(
        None, description="the last frame is the target pose; a frame before it gives its velocity (or give target_at)")
    target_at: TargetAt | None = Field(
        None, description="the place and facing to arrive at, the pose chosen by the engine (or give target); "
                          "the arrival is exact unless exact_arrival is false")

    @model_validator(mode="after")
    def _one_target(self) -> Any:
        if (self.target is None) == (self.target_at is None):
            raise ValueError('give exactly one of target (a pose: a Motion) or target_at (a place and facing: '
                             '{"x": cm, "z": cm, "yaw": degrees})')
        return self


# ---------------------------------------------------------------------- model description
class FrameRange(BaseModel):
    min: int
    max: int


class JointInfo(BaseModel):
    name: str
    parent: int
    offset: list[float]


class SkeletonInfo(BaseModel):
    joints: list[JointInfo]
    units: str
    up_axis: str
    handedness: str


class BuiltinStyleInfo(BaseModel):
    style_id: str = Field(description="builtin:NAME")
    name: str
    frames: int


class ModelInfo(BaseModel):
    """``GET /v1/model``: what a client needs to build requests and read frames."""

    name: str
    version: str
    fps: float
    context_frames: int
    max_transition_frames: int
    target_velocity_flag: bool = Field(
        description="true: the model is told whether a target came with the frame before it (one frame is enough); "
                    "false: a one-frame target is reached at rest")
    style_clip_frames: FrameRange
    skeleton: SkeletonInfo
    training_data: str
    license: str
    builtin_styles: list[BuiltinStyleInfo] = Field(
        default_factory=list, description="style codes shipped with the model: usable by every key as style_id")
    source: str = Field(default="network", description="what makes the motion (the server's RSMT_SOURCE): network, "
                                                       "matching (the model's motion database) or hybrid")


class ModelList(BaseModel):
    default: str
    models: list[ModelInfo]


# ---------------------------------------------------------------------- styles
class StyleCreate(BaseModel):
    """``POST /v1/styles``."""

    model_config = ConfigDict(extra="forbid",
                              json_schema_extra={"examples": [{"name": "proud", "motion": {"bvh": _EXAMPLE_BVH}}]})

    name: str = Field(min_length=1, max_length=200)
    motion: Motion | None = Field(None, description="the style clip (or give motions)")
    motions: list[Motion] | None = Field(
        None, min_length=1, max_length=MAX_STYLE_CLIPS,
        description=f"1 to {MAX_STYLE_CLIPS} clips of one style, on one rig, encoded together into one style (or "
                    "give motion); their order does not change the style or its id")
    model: ModelName | None = Field(None, description="model to encode for (default: the default model)")

    @model_validator(mode="after")
    def _one_motion(self) -> StyleCreate:
        if (self.motion is None) == (self.motions is None):
            raise ValueError("give exactly one of motion (one clip) or motions (1 to 5 clips)")
        return self

    @property
    def clips(self) -> list[BvhMotion | PoseMotion]:
        """The clips sent, as a list (one for ``motion``)."""
        return [self.motion] if self.motion is not None else list(self.motions or [])


class StyleInfo(BaseModel):
    style_id: str = Field(description="content hash of clip(s) + skeleton + model version (any replica recomputes it); "
                                      "builtin:NAME for a built-in style")
    name: str
    frames: int = Field(description="frames of the clip at the model's fps, of all its clips together for a style of "
                                    "several (of a built-in style: of the clip its code was encoded from)")
    clips: int = Field(1, description="the clips the style was encoded from (POST /v1/styles with motions: 1 to 5)")
    cached: bool = Field(description="true when this clip was already registered (nothing was encoded); always true "
                                     "for a built-in style")
    model: str
    builtin: bool = Field(False, description="true for a style shipped with the model (builtin:NAME): every key sees "
                                             "it, it counts against no key's styles and cannot be deleted")


class StyleList(BaseModel):
    styles: list[StyleInfo] = Field(description="the model's built-in styles (by name), then your registered ones "
                                                "(least recently used first), model by model")


# ---------------------------------------------------------------------- transitions
class Pose(BaseModel):
    root_position: list[float] = Field(description="[x, y, z] world position of the root joint")
    rotations: list[list[float]] = Field(description="[joints][x, y, z, w] local rotations")


class Timing(BaseModel):
    total: float = Field(description="ms from request arrival to response")
    engine: float = Field(description="ms in the engine (prepare + generate)")
    per_frame: float = Field(description="engine ms per generated frame")
    queue: float = Field(description="ms waiting for the model's worker")
    parse: float = Field(description="ms converting the Motion payloads")


class TransitionRequest(_TargetChoice, _StyleChoice, RequestControls):
    """``POST /v1/transition``."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"context": {"bvh": "..."}, "target": {"bvh": "..."}, "frames": 30,
                                          "style_id": "sty_0123456789abcdef01234567", "seed": 7,
                                          "deterministic": False, "output": "json"}]},
    )

    context: Motion = Field(description=">= context_frames frames; the last one is the current pose")
    frames: FrameCount = Field(description="frames to generate; the last is the arrival frame")
    seed: Seed | None = None
    deterministic: StrictBool = Field(False, description="no sampling noise")
    exact_arrival: StrictBool = Field(False, description="bend the last frames so the arrival frame equals the target pose")
    output: Literal["json", "bvh"] = "json"
    model: ModelName | None = None


class Reach(BaseModel):
    """Whether the target can be reached in the frames asked at the style's capture speed."""

    feasible: bool = Field(description="false: the root cannot cover distance_cm in frames at max_speed_cm_s")
    distance_cm: float = Field(description="ground distance from the root to the target's root")
    frames: int = Field(description="the frames asked for it")
    needed_frames: int = Field(description="the frames that distance takes at max_speed_cm_s")
    reachable_cm: float = Field(description="the most the root covers in frames at max_speed_cm_s")
    max_speed_cm_s: float = Field(description="the style's capture maximum root speed")


class TransitionJson(BaseModel):
    frames: list[Pose]
    fps: float
    model: str
    style_id: str
    timing_ms: Timing
    reach: Reach | None = Field(None, description="null: the model carries no gait limits")


class TransitionBvh(BaseModel):
    bvh: str = Field(description="BVH text of exactly `frames` frames at the model's fps")
    fps: float
    model: str
    style_id: str
    timing_ms: Timing
    reach: Reach | None = Field(None, description="null: the model carries no gait limits")


# ---------------------------------------------------------------------- health
class Health(BaseModel):
    status: str
    models: list[str] = []


class ErrorBody(BaseModel):
    code: str
    message: str


class ErrorEnvelope(BaseModel):
    error: ErrorBody


ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    status: {"model": ErrorEnvelope, "description": text}
    for status, text in (
        (400, "invalid JSON"), (401, "missing or wrong API key"), (404, "unknown model or style"),
        (405, "method not allowed (a built-in style cannot be deleted)"), (413, "payload too large"),
        (422, "invalid request or motion"), (429, "rate limited"),
        (503, "not ready or shutting down"),
    )
}


# ---------------------------------------------------------------------- WebSocket client messages
class _WsMessage(BaseModel):
    model_config = ConfigDict(extra="forbid")
    request_id: RequestId = None


class StartMessage(_WsMessage, _TargetChoice, _StyleChoice, RequestControls):
    type: Literal["start"]
    character: CharacterId | None = None
    context: Motion
    frames: FrameCount
    seed: Seed | None = None
    deterministic: StrictBool = False
    exact_arrival: StrictBool = False
    retargeted: StrictBool = False  # a resume of a character retargeted mid-motion: its facing takes the retarget window
    pace: Literal["realtime", "asap"] = "realtime"
    model: ModelName | None = None


class RetargetMessage(_WsMessage):
    type: Literal["retarget"]
    character: CharacterId
    target: Motion | None = None
    frames: FrameCount | None = None

    @model_validator(mode="after")
    def _something(self) -> RetargetMessage:
        if self.target is None and self.frames is None:
            raise ValueError("retarget needs a target and/or frames")
        return self


class StyleMessage(_WsMessage, _StyleChoice):
    type: Literal["style"]
    character: CharacterId


class CancelMessage(_WsMessage):
    type: Literal["cancel"]
    character: CharacterId


class PingMessage(_WsMessage):
    type: Literal["ping"]
    id: str | int | float | None = None


ClientMessage = Annotated[
    StartMessage | RetargetMessage | StyleMessage | CancelMessage | PingMessage, Field(discriminator="type")
]
CLIENT_MESSAGE = TypeAdapter(ClientMessage)
CLIENT_TYPES = ("start", "retarget", "style", "cancel", "ping")
