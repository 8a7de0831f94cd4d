"""Style clips: register (encode once, cache by content hash), list, get, delete."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Query, Response

from service.deps import RegistryDep
from service.engine_jobs import register_style, style_info
from service.errors import ServiceError
from service.http.auth import require_access
from service.registry import Registry
from service.schemas import (
    ERROR_RESPONSES,
    ModelName,
    StyleCreate,
    StyleId,
    StyleInfo,
    StyleList,
)

router = APIRouter(prefix="/v1/styles", tags=["styles"], dependencies=[Depends(require_access)],
                   responses={k: ERROR_RESPONSES[k] for k in (401, 429, 503)})


@router.post("", status_code=201, response_model=StyleInfo,
             responses={k: ERROR_RESPONSES[k] for k in (400, 404, 413, 422)},
             summary="register a style clip; the same clip always gets the same id (cached: true on a repeat)")
async def create_style(body: StyleCreate, registry: RegistryDep) -> dict:
    model = registry.get(body.model)
    return await model.run(register_style, model, body.motion, body.name)


def _find(registry: Registry, style_id: str) -> dict:
    for model in registry:
        style = model.engine.styles.peek(style_id)
        if style is not None:
            return style_info(model, style, True)
    raise ServiceError("unknown_style", f"no style {style_id!r}: register the clip with POST /v1/styles")


@router.get("", response_model=StyleList, summary="cached styles (of one model, or of all)")
async def list_styles(registry: RegistryDep, model: Annotated[ModelName | None, Query()] = None) -> dict:
    models = [registry.get(model)] if model is not None else sorted(registry, key=lambda m: m.name)
    styles = []
    for m in models:
        for sid in m.engine.styles.keys():
            style = m.engine.styles.peek(sid)
            if style is not None:
                styles.append(style_info(m, style, True))
    return {"styles": styles}


@router.get("/{style_id}", response_model=StyleInfo, responses={404: ERROR_RESPONSES[404]}, summary="one cached style")
async def get_style(style_id: StyleId, registry: RegistryDep) -> dict:
    return _find(registry, style_id)


@router.delete("/{style_id}", status_code=204, response_class=Response, responses={404: ERROR_RESPONSES[404]},
               summary="forget a style (characters already using it keep it)")
async def delete_style(style_id: StyleId, registry: RegistryDep) -> Response:
    deleted = [m.name for m in registry if m.engine.styles.delete(style_id)]
    if not deleted:
        raise ServiceError("unknown_style", f"no style {style_id!r}")
    return Response(status_code=204)
