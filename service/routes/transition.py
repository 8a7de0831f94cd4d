"""``POST /v1/transition``: a whole transition in one response, generated off the event loop."""

from __future__ import annotations

import time

from fastapi import APIRouter, Depends, Request, Response

from service.deps import RegistryDep, StateDep
from service.http.auth import CallerDep, require_access
from service.motion import dumps
from service.placed_targets import run_transition_at
from service.schemas import (
    ERROR_RESPONSES,
    TransitionBvh,
    TransitionJson,
    TransitionRequest,
)
from service.styles import registered_style
from service.work_queue import disconnect_of

router = APIRouter(prefix="/v1", tags=["transitions"], dependencies=[Depends(require_access)],
                   responses={k: ERROR_RESPONSES[k] for k in (400, 401, 404, 413, 422, 429, 503)})


@router.post(
    "/transition",
    response_model=TransitionJson | TransitionBvh,
    summary="generate `frames` frames from the context to the target in a style",
    description="Same input and seed give the same frames. `output: bvh` returns BVH text of exactly `frames` "
                "frames. The engine runs on the model's worker thread, so other requests keep flowing.",
)
async def transition(body: TransitionRequest, request: Request, registry: RegistryDep, state: StateDep,
                     caller: CallerDep) -> Response:
    arrived = time.perf_counter()
    model = registry.get(body.model)
    registered = await registered_style(state.store_lane, model, caller, body.style_id)  # the store's lane, not the work thread
    result = await model.run(run_transition_at, model, caller, body, arrived, registered, owner=caller.owner,
                             gone=disconnect_of(request.receive))
    result["timing_ms"]["total"] = round((time.perf_counter() - arrived) * 1e3, 3)
    state.metrics.transition_frames.labels(model.name).inc(body.frames)
    return Response(dumps(result), media_type="application/json")
