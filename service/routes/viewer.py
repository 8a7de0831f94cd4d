"""The web viewer: the page at ``/viewer/`` (static files, no build step) and its helper endpoints.

The page itself is plain files served as they are; everything it shows comes from the contract's
endpoints (``GET /v1/model``, ``/v1/styles``, ``POST /v1/transition``, ``/v1/stream``) plus two
helpers here that only the viewer needs: demo takes made on request and uploaded takes read onto the
model's rig. The helpers sit behind the same API key and rate limit as every other ``/v1`` route;
the static files carry no secrets and are served to anyone (the page asks for a key when needed).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Depends, FastAPI, Query, Response
from fastapi import Path as PathParam
from fastapi.staticfiles import StaticFiles

from service.auth import require_access
from service.deps import RegistryDep
from service.motion import dumps
from service.schemas import ERROR_RESPONSES, ModelName
from service.viewer import (
    ClipPoses,
    ClipRequest,
    DemoList,
    RigInfo,
    demo_list,
    demo_poses,
    rig_info,
    uploaded_poses,
)

STATIC_DIR = Path(__file__).resolve().parent.parent / "static" / "viewer"

router = APIRouter(prefix="/v1/viewer", tags=["viewer"], dependencies=[Depends(require_access)],
                   responses={k: ERROR_RESPONSES[k] for k in (401, 429, 503)})


@router.get("/rig", response_model=RigInfo, responses={404: ERROR_RESPONSES[404]},
            summary="joint roles of the model's skeleton (hips, shoulders, feet, mirror pairs)")
async def rig(registry: RegistryDep, model: Annotated[ModelName | None, Query()] = None) -> dict:
    return rig_info(registry.get(model))


@router.get("/demos", response_model=DemoList, summary="demo takes and style clips the viewer can load")
async def demos() -> dict:
    return demo_list()


@router.get("/demos/{name}", response_model=ClipPoses, responses={k: ERROR_RESPONSES[k] for k in (404, 422)},
            summary="a demo (procedural walk on the synthetic rig, made now) as JSON poses on the model's rig")
async def demo(name: Annotated[str, PathParam(max_length=64)], registry: RegistryDep,
               model: Annotated[ModelName | None, Query()] = None) -> Response:
    m = registry.get(model)
    return Response(dumps(await m.run(demo_poses, m, name)), media_type="application/json")


@router.post("/clip", response_model=ClipPoses, responses={k: ERROR_RESPONSES[k] for k in (400, 404, 413, 422)},
             summary="read a take (BVH text or JSON poses) onto the model's rig and fps, as JSON poses")
async def clip(body: ClipRequest, registry: RegistryDep) -> Response:
    m = registry.get(body.model)
    return Response(dumps(await m.run(uploaded_poses, m, body)), media_type="application/json")


class _RevalidatedFiles(StaticFiles):
    """Static files that browsers revalidate on every load (a cheap 304 by ETag): the modules import each
    other, so a page must never mix files cached from an older version of the service with newer ones."""

    def file_response(self, *args: Any, **kwargs: Any) -> Response:
        response = super().file_response(*args, **kwargs)
        response.headers["Cache-Control"] = "no-cache"
        return response


def install(app: FastAPI) -> None:
    """Add the helper routes and serve the page: ``/viewer`` redirects to ``/viewer/`` (index.html).

    A trailing-slash URL lets the page use relative links, so it also works behind a path prefix.
    """
    app.include_router(router)
    app.mount("/viewer", _RevalidatedFiles(directory=STATIC_DIR, html=True), name="viewer")
