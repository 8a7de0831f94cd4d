"""The joint roles of a model's skeleton, as the viewer needs them to measure facing as the model does."""

from __future__ import annotations

from typing import Any

from service.registry import LoadedModel


def rig_info(model: LoadedModel) -> dict[str, Any]:
    r = model.engine.skeleton.roles
    roles = {k: getattr(r, k) for k in ("root", "head", "left_hip", "right_hip", "left_shoulder", "right_shoulder")}
    roles.update(left_foot=list(r.left_foot), right_foot=list(r.right_foot), mirror=list(r.mirror))
    return {"model": model.name, "profile": r.profile, "roles": roles}
