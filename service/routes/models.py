"""The served models: ``GET /v1/model`` (the default), ``/v1/models`` and ``/v1/models/{name}``."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from service.deps import RegistryDep
from service.http.auth import require_access
from service.schemas import ERROR_RESPONSES, ModelInfo, ModelList

router = APIRouter(prefix="/v1", tags=["models"], dependencies=[Depends(require_access)],
                   responses={k: ERROR_RESPONSES[k] for k in (401, 429, 503)})


@router.get("/model", response_model=ModelInfo, summary="the default model: fps, limits, skeleton, licence")
async def default_model(registry: RegistryDep) -> dict:
    return registry.get().info()


@router.get("/models", response_model=ModelList, summary="every loaded model")
async def list_models(registry: RegistryDep) -> dict:
    return {"default": registry.default, "models": [m.info() for m in sorted(registry, key=lambda m: m.name)]}


@router.get("/models/{name}", response_model=ModelInfo, responses={404: ERROR_RESPONSES[404]},
            summary="one model by name")
async def get_model(name: str, registry: RegistryDep) -> dict:
    return registry.get(name).info()
