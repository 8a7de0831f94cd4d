"""Style clips: register (encode once, cache by content hash), list, get, delete; each API key sees only the
styles it registered (:mod:`service.style_book`), an admin key everyone's."""

from __future__ import annotations

import asyncio
from typing import Annotated

from fastapi import APIRouter, Depends, Query, Request, Response

from service.deps import RegistryDep
from service.engine_jobs import register_style, style_info
from service.errors import ServiceError
from service.http.auth import CallerDep, require_access
from service.registry import Registry
from service.schemas import (
    ERROR_RESPONSES,
    ModelName,
    StyleCreate,
    StyleId,
    StyleInfo,
    StyleList,
)
from service.style_book import Caller
from service.work_queue import disconnect_of

router = APIRouter(prefix="/v1/styles", tags=["styles"], dependencies=[Depends(require_access)],
                   responses={k: ERROR_RESPONSES[k] for k in (401, 429, 503)})


@router.post("", status_code=201, response_model=StyleInfo,
             responses={k: ERROR_RESPONSES[k] for k in (400, 404, 413, 422)},
             summary="register a style clip under your API key; the same clip always gets the same id "
                     "(cached: true when you registered it already)")
async def create_style(body: StyleCreate, request: Request, registry: RegistryDep, caller: CallerDep) -> dict:
    model = registry.get(body.model)
    return await model.run(register_style, model, caller, body.motion, body.name, gone=disconnect_of(request.receive))


def _find(registry: Registry, caller: Caller, style_id: str) -> dict:
    for model in sorted(registry, key=lambda m: m.name):
        style = model.book.peek(caller, style_id)
        if style is not None:
            return style_info(model, style, True)
    raise ServiceError("unknown_style", f"no style {style_id!r} under this API key: register the clip with "
                                        "POST /v1/styles")


@router.get("", response_model=StyleList, summary="your registered styles (of one model, or of all); an admin key's: "
                                                   "everyone's")
async def list_styles(registry: RegistryDep, caller: CallerDep,
                      model: Annotated[ModelName | None, Query()] = None) -> dict:
    models = [registry.get(model)] if model is not None else sorted(registry, key=lambda m: m.name)
    # Off the event loop: with RSMT_STYLE_STORE=redis each store call is a round trip (or a timeout).
    listed = await asyncio.to_thread(lambda: [(m, s) for m in models for s in m.book.styles_of(caller)])
    return {"styles": [style_info(m, style, True) for m, style in listed]}


@router.get("/{style_id}", response_model=StyleInfo, responses={404: ERROR_RESPONSES[404]},
            summary="one of your registered styles")
async def get_style(style_id: StyleId, registry: RegistryDep, caller: CallerDep) -> dict:
    return await asyncio.to_thread(_find, registry, caller, style_id)


@router.delete("/{style_id}", status_code=204, response_class=Response, responses={404: ERROR_RESPONSES[404]},
               summary="forget one of your styles (characters already using it keep it; an admin key's: everyone's)")
async def delete_style(style_id: StyleId, registry: RegistryDep, caller: CallerDep) -> Response:
    deleted = await asyncio.to_thread(lambda: [m.name for m in registry if m.book.delete(caller, style_id)])
    if not deleted:
        raise ServiceError("unknown_style", f"no style {style_id!r} under this API key")
    return Response(status_code=204)
