"""Style clips: register (encode once, cache by content hash), list, get, delete; each API key sees only the
styles it registered (:mod:`service.styles.book`), an admin key everyone's. Every key also sees the models'
built-in styles (``builtin:NAME``, :mod:`service.styles.builtin`): listed and fetched here, never deleted."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Query, Request, Response

from service.caller import Caller
from service.deps import RegistryDep
from service.errors import ServiceError
from service.http.auth import CallerDep, require_access
from service.registry import LoadedModel, Registry
from service.schemas import (
    ERROR_RESPONSES,
    ModelName,
    StyleCreate,
    StyleId,
    StyleInfo,
    StyleList,
)
from service.styles import (
    builtin_list,
    builtin_suggestion,
    encode_clips_registration,
    encode_registration,
    file_style,
    is_builtin,
    on_lane,
    style_info,
)
from service.work_queue import disconnect_of

router = APIRouter(prefix="/v1/styles", tags=["styles"], dependencies=[Depends(require_access)],
                   responses={k: ERROR_RESPONSES[k] for k in (401, 429, 503)})


def _builtins(model: LoadedModel) -> list[dict[str, Any]]:
    return [{**s, "cached": True, "model": model.name, "builtin": True} for s in builtin_list(model.engine)]


@router.post("", status_code=201, response_model=StyleInfo,
             responses={k: ERROR_RESPONSES[k] for k in (400, 404, 413, 422)},
             summary="register a style clip (motion), or 1 to 5 clips of one style (motions), under your API key; "
                     "the same clip(s) always get the same id (cached: true when you registered them already)")
async def create_style(body: StyleCreate, request: Request, registry: RegistryDep, caller: CallerDep) -> dict:
    model = registry.get(body.model)
    gone = disconnect_of(request.receive)
    if body.motion is not None:
        style, clip = await model.run(encode_registration, model, body.motion, body.name, owner=caller.owner, gone=gone)
        clips = [clip]
    else:
        style, clips = await model.run(encode_clips_registration, model, body.clips, body.name, owner=caller.owner,
                                        gone=gone)
    had = await file_style(request.app.state.service.store_lane, model, caller.owner, style, clips)  # the store's lane
    return style_info(model, style, had)


def _find(registry: Registry, caller: Caller, style_id: str) -> dict:
    for model in sorted(registry, key=lambda m: m.name):
        if is_builtin(style_id):
            found = [s for s in _builtins(model) if s["style_id"] == style_id]
            if found:
                return found[0]
            continue
        style = model.book.peek(caller, style_id)
        if style is not None:
            return style_info(model, style, True)
    if is_builtin(style_id):
        raise ServiceError("unknown_style", f"no model has the built-in style {style_id!r} (GET /v1/styles lists them)")
    raise ServiceError("unknown_style", f"no style {style_id!r} under this API key: register the clip with "
                                        "POST /v1/styles."
                                        + builtin_suggestion(style_id, (n for m in registry for n in m.engine.bundle.styles)))


@router.get("", response_model=StyleList,
            summary="the models' built-in styles (builtin: true) and your registered styles (of one model, or of all); "
                    "an admin key's: everyone's")
async def list_styles(request: Request, registry: RegistryDep, caller: CallerDep,
                      model: Annotated[ModelName | None, Query()] = None) -> dict:
    models = [registry.get(model)] if model is not None else sorted(registry, key=lambda m: m.name)
    # On the store's lane: with RSMT_STYLE_STORE=redis each store call is a round trip (or a timeout).
    listed = await on_lane(request.app.state.service.store_lane, lambda: [(m, m.book.styles_of(caller)) for m in models])
    return {"styles": [info for m, styles in listed
                       for info in [*_builtins(m), *(style_info(m, s, True) for s in styles)]]}


@router.get("/{style_id}", response_model=StyleInfo, responses={404: ERROR_RESPONSES[404]},
            summary="one of your registered styles, or a built-in one")
async def get_style(style_id: StyleId, request: Request, registry: RegistryDep, caller: CallerDep) -> dict:
    return await on_lane(request.app.state.service.store_lane, _find, registry, caller, style_id)


@router.delete("/{style_id}", status_code=204, response_class=Response,
               responses={k: ERROR_RESPONSES[k] for k in (404, 405)},
               summary="forget one of your styles (characters already using it keep it; an admin key's: everyone's); "
                       "built-in styles cannot be deleted (405)")
async def delete_style(style_id: StyleId, request: Request, registry: RegistryDep, caller: CallerDep) -> Response:
    if is_builtin(style_id):
        owners = sorted(m.name for m in registry if any(s["style_id"] == style_id for s in builtin_list(m.engine)))
        if owners:
            raise ServiceError("method_not_allowed", f"{style_id} is a built-in style of model {owners[0]!r} (shipped in "
                                                     "its bundle): it cannot be deleted; DELETE /v1/styles/ID forgets "
                                                     "styles you registered")
        raise ServiceError("unknown_style", f"no model has the built-in style {style_id!r} (GET /v1/styles lists them)")
    deleted = await on_lane(request.app.state.service.store_lane,
                            lambda: [m.name for m in registry if m.book.delete(caller, style_id)])
    if not deleted:
        raise ServiceError("unknown_style", f"no style {style_id!r} under this API key")
    return Response(status_code=204)
