"""The ``rsmt serve`` command: the HTTP/WebSocket service under uvicorn, with a bounded graceful shutdown."""

from __future__ import annotations

import argparse
import functools
import inspect
import socket
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import uvicorn
    from fastapi import FastAPI

    from service.settings import Settings


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
    p.add_argument("--log-format", choices=["text", "json"],
                   help="text lines, or one JSON object per line (default: RSMT_LOG_FORMAT if set, else text on a "
                        "terminal and json otherwise). Either way a line says where the service is once it is ready, "
                        "and another when it has stopped")
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

    from service.http.connection_guard import GuardedHttpToolsProtocol
    from service.http.logs import log_config

    fmt = choose_log_format(args.log_format, settings)
    common: dict[str, Any] = {
        "host": settings.host, "port": settings.port, "log_config": log_config(settings.log_level, fmt),
        "access_log": settings.access_log, "ws_max_size": settings.ws_max_message_bytes,
        "ws_per_message_deflate": settings.ws_per_message_deflate,
        "timeout_graceful_shutdown": settings.shutdown_grace_s, "lifespan": "on",
        # Forwarded headers only from the configured proxies: uvicorn's default trusts 127.0.0.1 (and
        # FORWARDED_ALLOW_IPS), which would let any local client pick its address for the rate limit.
        "proxy_headers": bool(settings.forwarded_allow_ips),
        "forwarded_allow_ips": ",".join(settings.forwarded_allow_ips) or None,
        # httptools with read timeouts for headers, bodies and WebSocket handshakes and a cap on connections
        # per client address (RSMT_HEADER_TIMEOUT_S, ...; service/http/connection_guard.py).
        "http": GuardedHttpToolsProtocol,
    }
    # Bound before the app is made, so that the app knows its port even when the OS picks it (--port 0).
    config = uvicorn.Config(serve_app, factory=True, workers=args.workers, **common)
    sock = config.bind_socket()
    settings = settings.model_copy(update={"port": sock.getsockname()[1], "log_format": fmt})
    if args.workers > 1:
        # Each worker process builds its own app from these settings (pickled with uvicorn's config).
        config.app = functools.partial(serve_app, settings)
        _supervise(config, sock)
        return 0
    config.app, config.factory = serve_app(settings), False
    server = uvicorn.Server(config)
    server.run(sockets=[sock])
    return 0 if server.started else 1


def serve_app(settings: Settings) -> FastAPI:
    """The service's app, knowing the address it is served at (for its ready and stopped lines)."""
    from service.app import create_app

    app = create_app(settings)
    app.state.public_url = public_url(settings.host, settings.port)
    return app


def public_url(host: str, port: int) -> str:
    """The URL to open for a bound address: loopback for the any-address (0.0.0.0, ::), brackets for IPv6."""
    host = {"": "127.0.0.1", "0.0.0.0": "127.0.0.1", "::": "::1"}.get(host, host)
    return f"http://[{host}]:{port}" if ":" in host else f"http://{host}:{port}"


def choose_log_format(option: str | None, settings: Settings) -> str:
    """``--log-format`` if given, else ``RSMT_LOG_FORMAT`` if set, else text for a terminal and JSON for the rest."""
    if option is not None:
        return option
    if "log_format" in settings.model_fields_set:  # RSMT_LOG_FORMAT
        return settings.log_format
    return "text" if sys.stderr.isatty() else "json"


def _supervise(config: uvicorn.Config, sock: socket.socket) -> None:
    """Run ``config.workers`` worker processes under uvicorn's supervisor, as ``uvicorn.run`` does; that
    accepts only an import string for several workers, which would leave the workers only the environment
    to read their settings from. Up to uvicorn 0.50 (at least) the supervisor also took the server's ``run``."""
    import uvicorn
    from uvicorn.supervisors import Multiprocess

    extra: dict[str, Any] = {}
    if "target" in inspect.signature(Multiprocess).parameters:
        extra["target"] = uvicorn.Server(config).run
    Multiprocess(config, sockets=[sock], **extra).run()
