"""The API's documentation pages, served with nothing fetched from outside, and ``GET /``.

FastAPI's own ``/docs`` and ``/redoc`` load Swagger UI and ReDoc from a CDN, so offline they are blank
pages; the app is built without them (``docs_url=None, redoc_url=None``) and :func:`install` serves the
same pages with the scripts and styles that the ``fastapi-offline`` package ships (Swagger UI, ReDoc;
MIT licensed), mounted at ``/docs/static``. The schema itself stays FastAPI's ``/openapi.json``.
The pages' Content-Security-Policy keeps the browser on this server: ReDoc's menu would otherwise
fetch a logo from its CDN (it hides the image when that fails). ``GET /`` redirects to the web viewer.

Every documentation route is here: :data:`router` for the pages (its ``dependencies`` are where an
access check for them goes) and :func:`install` for the static files and the schema's URL.
"""

from __future__ import annotations

from importlib.resources import files

from fastapi import APIRouter, FastAPI, Request
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html, get_swagger_ui_oauth2_redirect_html
from fastapi.responses import HTMLResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles

DOCS_URL = "/docs"
REDOC_URL = "/redoc"
OAUTH2_REDIRECT_URL = "/docs/oauth2-redirect"
STATIC_URL = "/docs/static"
ASSETS = files("fastapi_offline") / "static"  # swagger-ui-bundle.js, swagger-ui.css, redoc.standalone.js, favicon.png

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


@router.get(DOCS_URL)
async def swagger_ui(request: Request) -> HTMLResponse:
    root, app = _root(request), request.app
    return _local_only(get_swagger_ui_html(
        openapi_url=f"{root}{app.openapi_url}", title=f"{app.title} - Swagger UI",
        oauth2_redirect_url=f"{root}{OAUTH2_REDIRECT_URL}",
        swagger_js_url=f"{root}{STATIC_URL}/swagger-ui-bundle.js", swagger_css_url=f"{root}{STATIC_URL}/swagger-ui.css",
        swagger_favicon_url=f"{root}{STATIC_URL}/favicon.png", swagger_ui_parameters=app.swagger_ui_parameters))


@router.get(OAUTH2_REDIRECT_URL)
async def swagger_ui_redirect() -> HTMLResponse:
    return get_swagger_ui_oauth2_redirect_html()


@router.get(REDOC_URL)
async def redoc(request: Request) -> HTMLResponse:
    root, app = _root(request), request.app
    return _local_only(get_redoc_html(openapi_url=f"{root}{app.openapi_url}", title=f"{app.title} - ReDoc",
                                      redoc_js_url=f"{root}{STATIC_URL}/redoc.standalone.js",
                                      redoc_favicon_url=f"{root}{STATIC_URL}/favicon.png", with_google_fonts=False))


def install(app: FastAPI) -> None:
    """Serve the documentation pages, their static files and ``GET /`` (the app must have docs_url=None, redoc_url=None)."""
    app.mount(STATIC_URL, StaticFiles(directory=str(ASSETS)), name="docs-static")
    app.include_router(router)
