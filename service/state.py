"""What the lifespan puts on ``app.state.service``: settings, models, metrics, readiness, open connections."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from service.metrics import Metrics
from service.ratelimit import RateLimiter
from service.settings import Settings
from service.styles import StoreLane

if TYPE_CHECKING:
    from service.registry import Registry
    from service.streaming.connection import Connection


class Phase(enum.Enum):
    STARTING = "starting"  # models loaded or loading, warm-up running
    READY = "ready"
    STOPPING = "stopping"  # readiness 503, WebSockets closed, draining
    FAILED = "failed"  # warm-up failed: never ready (the process exits when it runs under uvicorn)


@dataclass(eq=False)
class ServiceState:
    settings: Settings
    metrics: Metrics
    limiter: RateLimiter
    auth_failures: RateLimiter  # requests with a missing or wrong key, per client address
    registry: Registry | None = None
    phase: Phase = Phase.STARTING
    connections: set[Connection] = field(default_factory=set)
    reserved_characters: int = 0  # starts being prepared, counted against max_characters
    failure: str = ""
    store_lane: StoreLane = field(default_factory=lambda: StoreLane(4, 1.0))  # style-store calls (create_app sets it)
    #: WebSocket messages per API key (per address without keys), every connection's together (create_app sets it).
    message_budgets: RateLimiter = field(default_factory=lambda: RateLimiter(0.0, 1))

    @property
    def ready(self) -> bool:
        return self.phase is Phase.READY and self.registry is not None

    @property
    def stopping(self) -> bool:
        return self.phase is Phase.STOPPING
