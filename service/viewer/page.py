"""The viewer's page: plain files (``static/``) served at ``/viewer/`` as they are, no build step.

The files carry no secrets and are served to anyone; the page asks for an API key when the
service needs one, and everything it shows comes from the contract's endpoints plus the helper
routes of :mod:`service.routes.viewer`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fastapi import FastAPI, Response
from fastapi.staticfiles import StaticFiles

STATIC_DIR = Path(__file__).resolve().parent / "static"


class _RevalidatedFiles(StaticFiles):
    """Static files that browsers revalidate on every load (a cheap 304 by ETag): the modules import each
    other, so a page must never mix files cached from an older version of the service with newer ones."""

    def file_response(self, *args: Any, **kwargs: Any) -> Response:
        response = super().file_response(*args, **kwargs)
        response.headers["Cache-Control"] = "no-cache"
        return response


def mount_page(app: FastAPI) -> None:
    """Serve the page: ``/viewer`` redirects to ``/viewer/`` (index.html).

    A trailing-slash URL lets the page use relative links, so it also works behind a path prefix.
    """
    app.mount("/viewer", _RevalidatedFiles(directory=STATIC_DIR, html=True), name="viewer")
