"""Service settings, read from ``RSMT_*`` environment variables (or passed to ``create_app``)."""

from __future__ import annotations

import os
import warnings
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import Field, create_model, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from model.inference.declared_settings import SETTINGS, Setting

if TYPE_CHECKING:
    from model.inference.overrides import Overrides

# Settings renamed to the one name the bundle and the CLI use; the old names still work until the next release.
RENAMED = {"output_smoothing": "smoothing", "output_root_smoothing": "root_smoothing"}


def _default_models() -> Path:
    # Imported lazily: model.inference.bundle imports torch, and nothing heavy runs at import time.
    from model.inference.bundle import DEFAULT_BUNDLE

    return DEFAULT_BUNDLE


def _declared_field(setting: Setting) -> tuple[Any, Any]:
    """The settings field of an engine setting: ``<kind> | None`` (None: each bundle's own), its declared range."""
    number = setting.kind != "switch"
    high = setting.high if number else None
    description = f"{setting.help}, {setting.range_words('true or false')} (default: each bundle's own)"
    return setting.python_type | None, Field(default=None, description=description, ge=setting.low if number else None,
                                             lt=high if setting.high_open else None,
                                             le=None if setting.high_open else high)


# The engine settings a caller may override (model.inference.declared_settings), one field each: RSMT_SMOOTHING, ...
# Read them through Settings.overrides(); type checkers see only the plain base.
if TYPE_CHECKING:
    _DeclaredSettings = BaseSettings
else:
    _DeclaredSettings = create_model("_DeclaredSettings", __base__=BaseSettings,
                                     **{s.name: _declared_field(s) for s in SETTINGS})


class Settings(_DeclaredSettings):
    """Every knob of the service. Environment: ``RSMT_<FIELD>`` (e.g. ``RSMT_PORT=9000``).

    List settings (``RSMT_API_KEYS``) take a comma-separated string or a JSON list.
    """

    model_config = SettingsConfigDict(env_prefix="RSMT_", extra="ignore", validate_default=True)

    # ------------------------------------------------------------------ network
    host: str = "127.0.0.1"
    port: int = Field(default=8000, ge=0, le=65535)

    # ------------------------------------------------------------------ models
    models: Path | None = Field(
        default=None,
        description="a bundle directory, or a directory whose subdirectories are bundles "
        "(default: the bundled default model, model/default_bundle)",
    )
    default_model: str | None = Field(default=None, description="name served by GET /v1/model (default: the first, by name)")
    threads: int = Field(default=1, ge=0, description="torch intra-op threads (0: torch's choice); process-wide")
    backend: Literal["torch", "onnxruntime"] = Field(
        default="torch", description="what runs the per-frame step and output steps: torch (traced graphs, the int8 "
        "LSTM where a bundle asks for it) or onnxruntime (the same graphs as ONNX, float32; needs the onnx extra)")
    source: Literal["network", "matching", "hybrid"] = Field(
        default="network", description="what makes the motion: network (the bundle's network), matching (windows of "
        "its motion database played onto each request) or hybrid (those windows where they match the request, the "
        "network elsewhere); matching and hybrid need a bundle with a motion database (rsmt bundle database) and the "
        "torch backend")
    request_threads: int = Field(
        default=1, ge=1, le=64, description="worker threads per model for HTTP requests and stream setup")
    warmup_max_batch: int = Field(
        default=64, ge=1, description="warm the batched step at 1, 2, 4, ... up to this many characters")
    # The output steps and the int8 LSTM (smoothing, foot_lock, ...): the fields of _DeclaredSettings.
    eager: bool = Field(
        default=False, description="run each model's per-frame step and output steps in eager PyTorch instead of their "
        "traced graphs (slower; for debugging)")

    # ------------------------------------------------------------------ style cache
    style_cache_entries: int = Field(default=1024, ge=1)
    style_cache_bytes: int = Field(default=256 << 20, ge=1)
    style_cache_entries_per_key: int = Field(
        default=256, ge=1, description="registered styles one API key may hold per model, a style of n clips counting n "
        "(its least recently used go first); with keys off the one anonymous owner is bounded by style_cache_entries "
        "alone")

    # -- style store (replicas)
    style_store: str = Field(
        default="memory", pattern=r"^(memory|rediss?://\S+|unix://\S+)$",
        description="where registered styles live: 'memory' (this process only, lost on restart) or a Redis URL "
        "redis://HOST:PORT/DB shared by every replica (service/styles/store)")
    style_store_ttl_s: int = Field(
        default=0, ge=0, description="with Redis: a registered style is forgotten this many seconds after it was last "
        "registered or used (0: never; the per-key cap still applies)")
    style_store_timeout_s: float = Field(
        default=1.0, gt=0, description="with Redis: connect and reply timeout; past it the request gets 503 "
        "style_store_unavailable")

    # ------------------------------------------------------------------ limits
    max_body_bytes: int = Field(default=1 << 20, ge=1024, description="HTTP request bodies above this get 413")
    max_clip_frames: int = Field(default=1200, ge=1, description="most frames one Motion payload may hold (before resampling)")
    max_transition_frames: int | None = Field(
        default=None, ge=1, description="cap on `frames` below the model's own max_transition_frames (default: the model's)"
    )
    quaternion_tolerance: float = Field(default=1e-2, gt=0, lt=1, description="JSON poses need | 1 - |q| | below this")
    max_abs_position: float = Field(
        default=1e6, gt=0, description="root positions and offsets beyond this (model units) are rejected")
    ws_max_message_bytes: int = Field(default=64 << 10, ge=1024, description="WebSocket messages above this close with 1009")
    ws_send_buffer_bytes: int = Field(
        default=256 << 10, ge=0, description="kernel send buffer of each WebSocket (0: the OS's autotuned default, up to "
        "net.ipv4.tcp_wmem max); bounds the memory a non-reading client holds and how soon it is noticed")
    ws_per_message_deflate: bool = Field(default=False, description="permessage-deflate on WebSockets (costs CPU per frame)")
    send_queue_frames: int = Field(
        default=16, ge=1, description="frames a character may have generated but not yet sent; the generator waits beyond it"
    )
    slow_client_grace_s: float = Field(
        default=5.0, gt=0, description="a character whose send queue stays full this long closes its connection with 1008"
    )
    idle_timeout_s: float = Field(
        default=60.0, gt=0, description="a connection without live characters or messages this long closes (1000)"
    )
    max_characters_per_connection: int = Field(default=64, ge=1)
    max_characters: int = Field(default=1024, ge=1, description="live streamed characters in the whole process")
    max_characters_per_key: int | None = Field(
        default=None, ge=1, description="live streamed characters one API key may drive, over all its connections "
        "(default with keys on: a quarter of max_characters, so one key cannot take every slot; with keys off: no "
        "share, max_characters alone)")
    asap_share: float = Field(
        default=0.1, ge=0.0, le=1.0, description="the largest share of time that steps of pace-asap characters may "
        "make realtime characters late: an asap step starts when it ends before the next realtime frame is due, and "
        "one that cannot (a batch whose step is longer than the gap) only on this share of the time (0: never)")
    step_shares: Literal["equal", "off"] | None = Field(
        default=None, description="per-key shares of the step budget: `equal` (each API key's characters step in "
        "batches of their own, and the key that has used the least step time goes first, so one key's many "
        "characters cannot slow another key's few) or `off` (every key's characters in the same batches). "
        "Default: equal with keys on, off with keys off")
    step_share_batch: int = Field(
        default=256, ge=1, description="with step shares on: the most characters of one key and pace in one batch "
        "(a key with more steps several batches, one after the other)")
    max_pending_messages: int = Field(
        default=1024, ge=16, description="control messages queued for one connection before it is closed (1008)"
    )
    ws_messages_per_s: float = Field(
        default=200.0, gt=0, description="messages one WebSocket connection may send per second, in bursts of up "
        "to twice this; the message past it closes the connection with 1008 before it is read")
    ws_max_queued_messages: int = Field(
        default=512, ge=1, description="messages one WebSocket connection has sent that wait to be handled (its "
        "earlier ones still being handled); one more closes the connection with 1008 before it is read")
    ws_key_messages_per_s: float = Field(
        default=2000.0, gt=0, description="messages all WebSocket connections of one API key (of one client address "
        "without keys) may send per second together, in bursts of up to twice this, each handshake counting one "
        "and a connection closed for going over a budget paying for the messages it left unread; past it the "
        "connection whose message found none left is closed with 1008, and new handshakes get 429 rate_limited "
        "until the budget refills")

    # -- work queue and shutdown
    queue_limit: int = Field(
        default=32, ge=1, description="per model and API key (with keys off: of everyone): HTTP requests that "
        "may wait for a work thread; beyond, 503 overloaded with Retry-After at once, to that key only (stream setup "
        "has its own threads and does not wait here)")

    # -- connection limits (slow clients)
    # Enforced by service.http.connection_guard (the uvicorn protocol `rsmt serve` runs), per process.
    header_timeout_s: float = Field(
        default=10.0, gt=0, description="a request's headers must be complete this long after its first byte (after "
        "the connection opened, for its first request); else 408 and the connection is closed")
    body_timeout_s: float = Field(
        default=30.0, gt=0, description="a request's whole body must arrive within this long of the end of its "
        "headers (a total, not a gap between chunks); else the connection is closed")
    ws_handshake_timeout_s: float = Field(
        default=10.0, gt=0, description="a WebSocket upgrade request must be answered (101 or refused) this long "
        "after its first byte; else the connection is closed. After the handshake idle_timeout_s applies")
    max_connections_per_address: int = Field(
        default=256, ge=0, description="open connections (HTTP and WebSocket) per client address as the socket "
        "sees it (IPv6 per /64); one more is closed at once. Peers in forwarded_allow_ips are not capped. 0: no cap")
    max_header_bytes: int = Field(
        default=32 << 10, ge=0, description="a request's line and headers together may hold this many bytes; past "
        "it 431 and nothing more of the connection is read (0: no cap)")
    max_header_line_bytes: int = Field(
        default=8 << 10, ge=0, description="one line of a request's head (its request line or one header) may hold "
        "this many bytes; past it 431 as for max_header_bytes (0: no cap)")
    write_timeout_s: float = Field(
        default=30.0, ge=0, description="a connection whose answers the client has not read for this long (the "
        "server's writes blocked on it) is closed; 0: never")
    pipelined_requests_per_s: float = Field(
        default=100.0, ge=0, description="HTTP requests one connection sends before the answer to its previous one "
        "(pipelined) are started at most this often per second, in bursts of up to this many, and nothing more of "
        "the connection is read while one waits; 0: no limit (requests sent after their previous answer are not "
        "limited by it)")

    # ------------------------------------------------------------------ auth and rate limits
    api_keys: Annotated[list[str], NoDecode] = Field(
        default_factory=list, description="accepted API keys; empty: no authentication"
    )
    admin_api_keys: Annotated[list[str], NoDecode] = Field(
        default_factory=list, description="API keys that are accepted too and also see, use and delete every key's "
        "registered styles")
    rate_limit_per_s: float = Field(default=0.0, ge=0,
                                    description="requests per second per key (per client address without keys); 0: off")
    rate_limit_burst: int = Field(default=20, ge=1, description="token-bucket size of the per-key rate limit")
    auth_failure_burst: int = Field(
        default=20, ge=1, description="requests with a missing or wrong API key one client address may make before "
        "the next get 429 rate_limited instead of 401 (a token bucket refilled at auth_failure_rate_per_s)")
    auth_failure_rate_per_s: float = Field(
        default=1.0, ge=0, description="refill rate of the per-address bucket of failed authentications; 0: no limit")
    rate_limit_max_tracked: int = Field(
        default=100_000, ge=1, description="most keys (or addresses) each rate limiter tracks, the per-key one and "
        "the failed-authentication one; past it the least recently seen are forgotten (they start again with a full "
        "burst). Each costs the same per request however many are tracked")
    open_docs_and_metrics: bool = Field(
        default=False, description="with API keys on, serve /metrics, /docs, /redoc and /openapi.json without a key")
    forwarded_allow_ips: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description="proxy addresses (or networks, or '*') whose X-Forwarded-For / X-Forwarded-Proto are trusted by "
        "`rsmt serve`; empty: none, the peer address is the client's (the keyless rate limit's key)")

    # ------------------------------------------------------------------ logs and lifecycle
    log_level: Literal["debug", "info", "warning", "error"] = "warning"
    log_format: Literal["json", "text"] = "json"
    access_log: bool = False
    shutdown_drain_s: float = Field(
        default=1.0, ge=0, description="after SIGTERM, readiness is 503 this long while requests are still served"
    )
    shutdown_grace_s: float = Field(default=8.0, gt=0, description="in-flight requests get this long to finish after the drain")

    @field_validator("api_keys", "admin_api_keys", "forwarded_allow_ips", mode="before")
    @classmethod
    def _split_keys(cls, value: object) -> object:
        if isinstance(value, str):
            text = value.strip()
            if text.startswith("["):
                import json

                return json.loads(text)
            return [k.strip() for k in text.split(",") if k.strip()]
        return value

    @field_validator("api_keys", "admin_api_keys")
    @classmethod
    def _check_keys(cls, keys: list[str]) -> list[str]:
        short = [k for k in keys if len(k) < 16]
        if short:
            raise ValueError("API keys must be at least 16 characters long (make one with "
                             "`python -c 'import secrets; print(secrets.token_urlsafe(24))'`)")
        return keys

    @model_validator(mode="before")
    @classmethod
    def _old_names(cls, data: object) -> object:
        """``output_smoothing`` / ``RSMT_OUTPUT_SMOOTHING`` (and the root's) still set their new names, with a warning."""
        if not isinstance(data, dict):
            return data
        data = dict(data)
        for old, new in RENAMED.items():
            value = data.pop(old, None)
            if value is None:
                value = os.environ.get(f"RSMT_{old.upper()}")
            if value is None:
                continue
            warnings.warn(f"the setting {old} (RSMT_{old.upper()}) is deprecated and goes in the next release: "
                          f"use {new} (RSMT_{new.upper()})", DeprecationWarning, stacklevel=2)
            data.setdefault(new, value)
        return data

    def overrides(self) -> Overrides:
        """What these settings change of every bundle's output steps and inference settings."""
        from model.inference.overrides import Overrides

        return Overrides(**{s.name: getattr(self, s.name) for s in SETTINGS})

    @model_validator(mode="after")
    def _resolve_models(self) -> Settings:
        if self.models is None:
            self.models = _default_models()
        return self

    @property
    def auth_enabled(self) -> bool:
        return bool(self.api_keys or self.admin_api_keys)

    @property
    def all_keys(self) -> list[str]:
        """Every accepted key: ``api_keys`` and ``admin_api_keys``."""
        return [*self.api_keys, *self.admin_api_keys]

    @property
    def characters_per_key(self) -> int | None:
        """The per-key share of the character slots: the setting, else a quarter of them with keys on."""
        if self.max_characters_per_key is not None:
            return self.max_characters_per_key
        return max(1, self.max_characters // 4) if self.auth_enabled else None

    @property
    def step_shares_on(self) -> bool:
        """Whether each API key gets its share of the step budget: the setting, else whether keys are on."""
        return self.auth_enabled if self.step_shares is None else self.step_shares == "equal"

    @property
    def styles_per_owner(self) -> int:
        """The per-owner style bound: the per-key cap with keys on, the whole bound without."""
        return self.style_cache_entries_per_key if self.auth_enabled else self.style_cache_entries


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """Settings from the environment, read once (the dependency ``create_app`` uses by default)."""
    return Settings()
