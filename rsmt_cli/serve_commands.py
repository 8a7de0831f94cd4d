"""The ``rsmt serve`` command: the HTTP/WebSocket service under uvicorn, with a bounded graceful shutdown."""

from __future__ import annotations

import argparse
import functools
import inspect
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import uvicorn


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "serve", help="serve the model over HTTP and WebSocket",
        description="Serve transitions over HTTP and WebSocket (docs/service.md). Every option also reads "
                    "from the environment (RSMT_HOST, RSMT_PORT, RSMT_MODELS, RSMT_THREADS, ...); options win.",
    )
    p.add_argument("--host", help="address to bind (default 127.0.0.1; 0.0.0.0 in the container)")
    p.add_argument("--port", type=int, help="port (default 8000)")
    p.add_argument("--models", type=Path, metavar="DIR",
                   help="a bundle directory, or a directory of bundle directories (default: the bundled default model)")
    p.add_argument("--threads", type=int, help="torch threads per process (default 1; 0: torch's choice)")
    p.add_argument("--workers", type=int, default=1,
                   help="processes (default 1). Each has its own models and style cache: a style_id registered "
                        "through one may be unknown to another, so clients re-register on 404 (ids are content hashes)")
    p.add_argument("--log-level", choices=["debug", "info", "warning", "error"], help="default warning")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from service.registry import NoModelError, find_bundles
    from service.settings import Settings

    # The options given override the environment; the rest of the settings come from it (RSMT_*).
    overrides = {"host": args.host, "port": args.port, "models": args.models, "threads": args.threads,
                 "log_level": args.log_level}
    settings = Settings(**{k: v for k, v in overrides.items() if v is not None})
    assert settings.models is not None
    try:
        find_bundles(settings.models)
    except NoModelError as exc:
        print(f"rsmt serve: {exc}", file=sys.stderr)
        return 2

    import uvicorn

    from service.app import create_app
    from service.http.logs import log_config

    common: dict[str, Any] = {
        "host": settings.host, "port": settings.port, "log_config": log_config(settings.log_level, settings.log_format),
        "access_log": settings.access_log, "ws_max_size": settings.ws_max_message_bytes,
        "ws_per_message_deflate": settings.ws_per_message_deflate,
        "timeout_graceful_shutdown": settings.shutdown_grace_s, "lifespan": "on",
    }
    if args.workers > 1:
        # Each worker process builds its own app from these settings (pickled with uvicorn's config).
        config = uvicorn.Config(functools.partial(create_app, settings), factory=True, workers=args.workers, **common)
        _supervise(config)
        return 0
    server = uvicorn.Server(uvicorn.Config(create_app(settings), **common))
    server.run()
    return 0 if server.started else 1


def _supervise(config: uvicorn.Config) -> None:
    """Run ``config.workers`` worker processes under uvicorn's supervisor, as ``uvicorn.run`` does; that
    accepts only an import string for several workers, which would leave the workers only the environment
    to read their settings from. Up to uvicorn 0.50 (at least) the supervisor also took the server's ``run``."""
    import uvicorn
    from uvicorn.supervisors import Multiprocess

    sock = config.bind_socket()
    extra: dict[str, Any] = {}
    if "target" in inspect.signature(Multiprocess).parameters:
        extra["target"] = uvicorn.Server(config).run
    Multiprocess(config, sockets=[sock], **extra).run()
