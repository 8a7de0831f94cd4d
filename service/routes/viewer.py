"""The web viewer's helper routes (``/v1/viewer/...``); its page is :mod:`service.viewer.page`.

Everything the page shows comes from the contract's endpoints (``GET /v1/model``, ``/v1/styles``,
``POST /v1/transition``, ``/v1/stream``) plus the helpers here that only the viewer needs: the rig's
joint roles, demo takes made on request (by the model itself, from a standing pose on its own
skeleton, where it has built-in styles) and uploaded takes read onto the model's rig. They sit
behind the same API key and rate limit as every other ``/v1`` route.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi import Path as PathParam

from service.deps import RegistryDep
from service.http.auth import CallerDep, require_access
from service.motion import dumps
from service.schemas import ERROR_RESPONSES, ModelName
from service.viewer.rig import rig_info
from service.viewer.schemas import ClipPoses, ClipRequest, DemoList, RigInfo
from service.viewer.takes import demo_list, demo_poses, uploaded_poses
from service.work_queue import disconnect_of

router = APIRouter(prefix="/v1/viewer", tags=["viewer"], dependencies=[Depends(require_access)],
                   responses={k: ERROR_RESPONSES[k] for k in (401, 429, 503)})


@router.get("/rig", response_model=RigInfo, responses={404: ERROR_RESPONSES[404]},
            summary="joint roles of the model's skeleton (hips, shoulders, feet, mirror pairs)")
async def rig(registry: RegistryDep, model: Annotated[ModelName | None, Query()] = None) -> dict:
    return rig_info(registry.get(model))


@router.get("/demos", response_model=DemoList, responses={404: ERROR_RESPONSES[404]},
            summary="demo takes (and style clips) on the model's rig that the viewer can load")
async def demos(registry: RegistryDep, model: Annotated[ModelName | None, Query()] = None) -> dict:
    return demo_list(registry.get(model))


@router.get("/demos/{name}", response_model=ClipPoses, responses={k: ERROR_RESPONSES[k] for k in (404, 422)},
            summary="a demo take as JSON poses on the model's rig (a walk the model generates from a standing "
                    "pose in a built-in style, or a procedural walk on the synthetic test rig)")
async def demo(name: Annotated[str, PathParam(max_length=64)], request: Request, registry: RegistryDep,
               caller: CallerDep, model: Annotated[ModelName | None, Query()] = None) -> Response:
    m = registry.get(model)
    return Response(dumps(await m.run(demo_poses, m, name, owner=caller.owner, gone=disconnect_of(request.receive))),
                    media_type="application/json")


@router.post("/clip", response_model=ClipPoses, responses={k: ERROR_RESPONSES[k] for k in (400, 404, 413, 422)},
             summary="read a take (BVH text or JSON poses) onto the model's rig and fps, as JSON poses")
async def clip(body: ClipRequest, request: Request, registry: RegistryDep, caller: CallerDep) -> Response:
    m = registry.get(body.model)
    return Response(dumps(await m.run(uploaded_poses, m, body, owner=caller.owner, gone=disconnect_of(request.receive))),
                    media_type="application/json")
