"""The API's documentation pages, served with nothing fetched from outside, and ``GET /``.

FastAPI's own ``/docs`` and ``/redoc`` load Swagger UI and ReDoc from a CDN, so offline they are blank
pages; the app is built without them (``docs_url=None, redoc_url=None``) and :func:`install` serves the
same pages with the scripts and styles that the ``fastapi-offline`` package ships (Swagger UI, ReDoc;
MIT licensed), mounted at ``/docs/static``. The schema itself stays FastAPI's ``/openapi.json``.
The pages' Content-Security-Policy keeps the browser on this server, and nothing on them asks for more:
ReDoc's script is served with the address of the logo its menu fetches from a CDN replaced by an empty
inline image (:data:`REDOC_JS_URL`), and Swagger UI's validator badge is off. ``GET /`` redirects to the
web viewer and ``GET /favicon.ico`` is the service's icon.

Every documentation route is here: :data:`router` for the pages (its ``dependencies`` are where an
access check for them goes) and :func:`install` for the static files and the schema's URL.
"""

from __future__ import annotations

from functools import cache
from importlib.resources import files

from fastapi import APIRouter, FastAPI, Request
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html, get_swagger_ui_oauth2_redirect_html
from fastapi.responses import HTMLResponse, RedirectResponse, Response
from fastapi.staticfiles import StaticFiles

DOCS_URL = "/docs"
REDOC_URL = "/redoc"
OAUTH2_REDIRECT_URL = "/docs/oauth2-redirect"
STATIC_URL = "/docs/static"
ASSETS = files("fastapi_offline") / "static"  # swagger-ui-bundle.js, swagger-ui.css, redoc.standalone.js, favicon.png
REDOC_JS_URL = "/docs/redoc.js"  # ReDoc's script without its one outside address (see _redoc_js)
REDOC_LOGO = "https://cdn.redoc.ly/redoc/logo-mini.svg"
EMPTY_IMAGE = "data:image/svg+xml,%3Csvg xmlns='http://www.w3.org/2000/svg' width='1' height='1'/%3E"
ICON = files("service.viewer") / "static" / "favicon.svg"

# Both pages run an inline script that starts them; ReDoc injects its styles and may start a blob: worker.
CSP = ("default-src 'self'; script-src 'self' 'unsafe-inline'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; "
       "worker-src 'self' blob:; connect-src 'self'; frame-ancestors 'self'")

router = APIRouter(include_in_schema=False)


def _root(request: Request) -> str:
    return str(request.scope.get("root_path", ""))


def _local_only(page: HTMLResponse) -> HTMLResponse:
    page.headers["Content-Security-Policy"] = CSP
    return page


@router.get("/")
async def home(request: Request) -> RedirectResponse:
    return RedirectResponse(f"{_root(request)}/viewer/", status_code=307)


@router.get("/favicon.ico")
async def favicon() -> Response:
    return Response(ICON.read_bytes(), media_type="image/svg+xml", headers={"Cache-Control": "max-age=86400"})


@router.get(DOCS_URL)
async def swagger_ui(request: Request) -> HTMLResponse:
    root, app = _root(request), request.app
    return _local_only(get_swagger_ui_html(
        openapi_url=f"{root}{app.openapi_url}", title=f"{app.title} - Swagger UI",
        oauth2_redirect_url=f"{root}{OAUTH2_REDIRECT_URL}",
        swagger_js_url=f"{root}{STATIC_URL}/swagger-ui-bundle.js", swagger_css_url=f"{root}{STATIC_URL}/swagger-ui.css",
        swagger_favicon_url=f"{root}/favicon.ico",
        # No validator badge: Swagger UI would fetch it from validator.swagger.io.
        swagger_ui_parameters={**(app.swagger_ui_parameters or {}), "validatorUrl": None}))


@router.get(OAUTH2_REDIRECT_URL)
async def swagger_ui_redirect() -> HTMLResponse:
    return get_swagger_ui_oauth2_redirect_html()


@router.get(REDOC_URL)
async def redoc(request: Request) -> HTMLResponse:
    root, app = _root(request), request.app
    return _local_only(get_redoc_html(openapi_url=f"{root}{app.openapi_url}", title=f"{app.title} - ReDoc",
                                      redoc_js_url=f"{root}{REDOC_JS_URL}", redoc_favicon_url=f"{root}/favicon.ico",
                                      with_google_fonts=False))


@cache
def _redoc_js() -> bytes:
    """``redoc.standalone.js`` with its menu's logo (the one address it fetches from outside) an empty image."""
    return (ASSETS / "redoc.standalone.js").read_text(encoding="utf-8").replace(REDOC_LOGO, EMPTY_IMAGE).encode()


@router.get(REDOC_JS_URL)
async def redoc_js() -> Response:
    return Response(_redoc_js(), media_type="text/javascript", headers={"Cache-Control": "max-age=86400"})


def install(app: FastAPI) -> None:
    """Serve the documentation pages, their static files and ``GET /`` (the app must have docs_url=None, redoc_url=None)."""
    app.mount(STATIC_URL, StaticFiles(directory=str(ASSETS)), name="docs-static")
    app.include_router(router)
