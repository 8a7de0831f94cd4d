"""``target_at``: a transition or a stream start whose target is a place and a facing, not a pose.

The engine picks the pose (:func:`model.inference.placed_target.placed_target`: the context's last pose, turned
and moved there) and the request goes on as one that named that pose as its ``target``. Its arrival is exact
(the arrival frame is the placed pose, so the place and facing are met) unless the request says
``"exact_arrival": false``. Both run on the model's work threads, as the jobs they wrap.
"""

from __future__ import annotations

from typing import Any, TypeVar

from model.inference.placed_target import Placement, placed_target
from service.caller import Caller
from service.engine_jobs import Prepared, prepare_character, run_transition
from service.motion import motion_to_clip
from service.registry import LoadedModel
from service.schemas import PoseMotion, StartMessage, TransitionRequest
from service.styles import Registered
from service.work_queue import Continue

Request = TypeVar("Request", TransitionRequest, StartMessage)


def with_placed_target(model: LoadedModel, req: Request) -> Request:
    """``req`` with its ``target_at`` made a target pose on the model's skeleton; ``req`` itself when it names a
    target."""
    at = req.target_at
    if at is None:
        return req
    context = motion_to_clip(req.context, model.engine, model.limits, "context")
    pose = placed_target(context, Placement(at.x, at.z, at.yaw))
    target = PoseMotion(root_positions=pose.root_positions.tolist(), rotations=pose.rotations.tolist(),
                        fps=float(pose.fps))
    exact = req.exact_arrival if "exact_arrival" in req.model_fields_set else True
    return req.model_copy(update={"target": target, "target_at": None, "exact_arrival": exact})


def run_transition_at(model: LoadedModel, caller: Caller, req: TransitionRequest, queued_at: float,
                      registered: Registered = None) -> dict[str, Any] | Continue[dict[str, Any]]:
    """:func:`service.engine_jobs.run_transition` of a request that may give ``target_at``."""
    return run_transition(model, caller, with_placed_target(model, req), queued_at, registered)


def prepare_character_at(model: LoadedModel, caller: Caller, msg: StartMessage, character_id: str,
                         registered: Registered = None) -> Prepared | Continue[Prepared]:
    """:func:`service.engine_jobs.prepare_character` of a start that may give ``target_at``."""
    return prepare_character(model, caller, with_placed_target(model, msg), character_id, registered)
