"""Liveness and readiness probes."""

from __future__ import annotations

from fastapi import APIRouter

from service.deps import StateDep
from service.errors import ServiceError
from service.schemas import ERROR_RESPONSES, Health

router = APIRouter(prefix="/v1/health", tags=["health"])


# Only the status (docs/api-contract.md): which models serve is readiness's answer, not liveness's.
@router.get("/live", response_model=Health, response_model_exclude_unset=True, summary="200 while the process runs")
async def live() -> Health:
    return Health(status="alive")


@router.get("/ready", response_model=Health, responses={503: ERROR_RESPONSES[503]},
            summary="200 once every model is loaded and warmed; 503 before that and while shutting down")
async def ready(state: StateDep) -> Health:
    if state.stopping:
        raise ServiceError("shutting_down", "the server is shutting down", headers={"Retry-After": "1"})
    if not state.ready:
        raise ServiceError("not_ready", state.failure or "models are loading or warming up", headers={"Retry-After": "1"})
    assert state.registry is not None
    return Health(status="ready", models=sorted(m.name for m in state.registry))
