"""The HTTP side of the contract without I/O: what each call sends, how answers and errors read.

Each endpoint is an *operation*: a generator that yields the :class:`Request` objects it needs
and is sent back each ``httpx.Response``; its return value is the call's result. The sync and
async clients (:mod:`rsmt_client.http`) only carry requests over the wire, so both behave the
same by construction::

    op = transition(state, ...)            # nothing sent yet
    request = next(op)                     # POST /v1/transition
    request = op.send(response)            # then GET /v1/model, when the joint names are not known yet
    ...                                    # StopIteration.value is the Poses
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Generator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import httpx

from rsmt_client._retry import RetryHook, Retrying, RetryPolicy, parse_retry_after
from rsmt_client.errors import RsmtError
from rsmt_client.placement import target_field

if TYPE_CHECKING:  # numpy loads with the first motion payload, not with the client (`rsmt client styles list`)
    from rsmt_client.motion import Poses
    from rsmt_client.motion_cuts import Cutter

DEFAULT_URL = "http://127.0.0.1:8000"
T = TypeVar("T")


def motion_payload(motion: Any) -> dict[str, Any]:
    """:func:`rsmt_client.motion.motion_payload`, imported on first use (it needs numpy)."""
    from rsmt_client.motion import motion_payload as payload

    return payload(motion)


@dataclass(frozen=True)
class Request:
    """One HTTP request of an operation (``json`` and ``params`` as httpx takes them)."""

    method: str
    path: str
    json: Any = None
    params: Mapping[str, str] | None = None


Operation = Generator[Request, httpx.Response, T]
REMEMBERED_STYLES = 256  # style clips a client keeps to register again (its most recently registered)
MAX_STYLE_CLIPS = 5  # the most clips one style is registered from (POST /v1/styles, motions)


@dataclass
class ClientState:
    """What a client knows between calls: where the server is, how to retry, the default model's description."""

    url: str
    api_key: str | None = None
    retry: RetryPolicy = field(default_factory=RetryPolicy)
    on_retry: RetryHook | None = None
    model_info: dict[str, Any] | None = None
    # The POST /v1/styles bodies of the styles registered through this client, by (model, style id): the
    # server keeps styles in memory only (evicted, lost on restart), so an unknown_style for one of them is
    # answered by registering it again.
    registered: OrderedDict[tuple[str | None, str], dict[str, Any]] = field(default_factory=OrderedDict)
    # What each model reads of a motion (by model name, None for the default), from its description.
    cutters: dict[str | None, Cutter] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.url = self.url.rstrip("/")

    def headers(self) -> dict[str, str]:
        headers = {"User-Agent": "rsmt-client/0.1", "Accept": "application/json"}
        if self.api_key:
            headers["X-API-Key"] = self.api_key
        return headers

    def retrying(self) -> Retrying:
        return Retrying(self.retry, self.on_retry)

    def remember(self, model_name: str | None, style_id: str, body: dict[str, Any]) -> None:
        self.registered[(model_name, style_id)] = body
        self.registered.move_to_end((model_name, style_id))
        while len(self.registered) > REMEMBERED_STYLES:
            self.registered.popitem(last=False)

    def joints(self) -> tuple[str, ...] | None:
        info = self.model_info
        return tuple(j["name"] for j in info["skeleton"]["joints"]) if info else None


def error_from_response(resp: httpx.Response) -> RsmtError:
    """The contract's ``{"error": {"code", "message"}}`` as an :class:`RsmtError` (any body survives)."""
    code, message = "http_error", resp.text[:500] or resp.reason_phrase
    try:
        body = resp.json()
        err = body.get("error") if isinstance(body, dict) else None
        if isinstance(err, dict):
            code, message = str(err.get("code", code)), str(err.get("message", message))
    except ValueError:
        pass
    return RsmtError(code, message, status=resp.status_code, retry_after=parse_retry_after(resp.headers.get("retry-after")))


def wait_after_response(retrying: Retrying, resp: httpx.Response) -> float | None:
    """None when ``resp`` is the answer; else the wait before trying again (or the error, raised)."""
    if resp.status_code < 400:
        return None
    return retrying.wait_or_raise(resp.status_code, resp.headers, error_from_response(resp), response=resp)


def wait_after_refusal(retrying: Retrying, url: str, exc: BaseException) -> float:
    """The wait after a connection that could not be made (or ``RsmtError("connection")``, raised)."""
    return retrying.wait_or_raise(None, None, RsmtError("connection", f"cannot reach {url}: {exc}"), cause=exc)


# The connection went away after the request was sent and before any answer (its replica died, or closed a
# keep-alive connection as it stopped). Every request of the contract but DELETE may be sent again: a
# transition has no side effect and a style's id is its content's hash; a DELETE replayed after it took
# effect would answer 404, so it is not. Timeouts are not here: a slow server would only get the work twice.
DROPPED = (httpx.RemoteProtocolError, httpx.ReadError, httpx.WriteError)


def wait_after_drop(retrying: Retrying, method: str, url: str, exc: BaseException) -> float:
    """The wait after a dropped connection (or ``RsmtError("connection")``, raised; at once for a DELETE)."""
    error = RsmtError("connection", f"{url} closed the connection without answering: {exc}")
    if method.upper() == "DELETE":
        raise error from exc
    return retrying.wait_or_raise(None, None, error, cause=exc)


# ---------------------------------------------------------------------- operations

def live() -> Operation[bool]:
    return (yield Request("GET", "/v1/health/live")).status_code == 200


def model(state: ClientState, name: str | None = None) -> Operation[dict[str, Any]]:
    info = (yield Request("GET", "/v1/model" if name is None else f"/v1/models/{name}")).json()
    if name is None:
        state.model_info = info
    return info


def demo(state: ClientState, name: str, model_name: str | None) -> Operation[Poses]:
    """A demo take of the web viewer (``GET /v1/viewer/demos/{name}``): motion on the model's own rig, e.g. a walk
    the default model generates in a built-in style (``walk-normal``, ``walk-elderly-turn-left``, ...)."""
    data = (yield Request("GET", f"/v1/viewer/demos/{name}", params={"model": model_name} if model_name else None)).json()
    info = state.model_info if model_name is None else None
    if info is None:
        info = yield from model(state, model_name)
    from rsmt_client.motion import Poses

    return Poses(data["root_positions"], data["rotations"], float(data["fps"]),
                 joints=tuple(j["name"] for j in info["skeleton"]["joints"]), model=info.get("name"))


def demos(model_name: str | None) -> Operation[list[dict[str, Any]]]:
    """The viewer's demo takes (``GET /v1/viewer/demos``): ``[{"name", "kind", "description"}]``."""
    return (yield Request("GET", "/v1/viewer/demos", params={"model": model_name} if model_name else None)).json()["demos"]


def cutter(state: ClientState, model_name: str | None) -> Operation[Cutter]:
    """What the model reads of a motion (:mod:`rsmt_client.motion_cuts`), asking for its description the first time."""
    from rsmt_client.motion_cuts import Cutter, ModelLimits

    found = state.cutters.get(model_name)
    if found is None:
        info = state.model_info if model_name is None else None
        if info is None:
            info = yield from model(state, model_name)
        found = state.cutters[model_name] = Cutter(ModelLimits.of(info))
    return found


def models() -> Operation[dict[str, Any]]:
    return (yield Request("GET", "/v1/models")).json()


def register_style(state: ClientState, motion: Any, name: str | None,
                   model_name: str | None) -> Operation[dict[str, Any]]:
    cuts = yield from cutter(state, model_name)
    body: dict[str, Any] = {"name": name or default_style_name(motion), "motion": cuts.style(motion_payload(motion))}
    if model_name is not None:
        body["model"] = model_name
    info = (yield Request("POST", "/v1/styles", json=body)).json()
    state.remember(model_name, info["style_id"], body)
    return info


def register_style_clips(state: ClientState, motions: Sequence[Any], name: str | None,
                         model_name: str | None) -> Operation[dict[str, Any]]:
    """``POST /v1/styles`` with ``motions``: 1 to 5 clips of one style, encoded together into one style (each clip
    cut to what the model reads, as :func:`register_style` cuts one)."""
    if not 1 <= len(motions) <= MAX_STYLE_CLIPS:
        raise ValueError(f"a style is registered from 1 to {MAX_STYLE_CLIPS} clips; got {len(motions)}")
    cuts = yield from cutter(state, model_name)
    body: dict[str, Any] = {"name": name or default_style_name(motions[0]),
                            "motions": [cuts.style(motion_payload(m)) for m in motions]}
    if model_name is not None:
        body["model"] = model_name
    info = (yield Request("POST", "/v1/styles", json=body)).json()
    state.remember(model_name, info["style_id"], body)
    return info


def styles(model_name: str | None) -> Operation[list[dict[str, Any]]]:
    return (yield Request("GET", "/v1/styles", params={"model": model_name} if model_name else None)).json()["styles"]


def style(style_id: str) -> Operation[dict[str, Any]]:
    return (yield Request("GET", f"/v1/styles/{style_id}")).json()


def delete_style(state: ClientState, style_id: str) -> Operation[None]:
    for key in [k for k in state.registered if k[1] == style_id]:  # deleted on purpose: not registered again
        del state.registered[key]
    yield Request("DELETE", f"/v1/styles/{style_id}")


def with_style(state: ClientState, request: Request, style_id: str | None,
               model_name: str | None) -> Operation[httpx.Response]:
    """Send ``request``; when the server answers ``unknown_style`` for a style this client registered (it was
    evicted, or the server restarted), register the clip again and send ``request`` once more.

    The clients throw each error answer into the operation, so this is where it is caught."""
    try:
        return (yield request)
    except RsmtError as exc:
        body = state.registered.get((model_name, style_id)) if style_id is not None else None
        if exc.code != "unknown_style" or body is None:
            raise
    yield Request("POST", "/v1/styles", json=body)
    return (yield request)


def transition(state: ClientState, context: Any, target: Any, frames: int, style_id: str | None, style_motion: Any,
               seed: int | None, deterministic: bool, model_name: str | None, exact_arrival: bool | None,
               style_strength: float | None = None) -> Operation[Poses]:
    cuts = yield from cutter(state, model_name)
    body = transition_body(context, target, frames, style_id, style_motion, seed, deterministic, "json", model_name,
                           exact_arrival, cuts, style_strength)
    data = (yield from with_style(state, Request("POST", "/v1/transition", json=body), style_id, model_name)).json()
    if state.model_info is None and model_name is None:
        yield from model(state)
    joints = state.joints() if model_name is None else None
    from rsmt_client.motion import Poses
    from rsmt_client.reach import Reach

    return Poses.from_frames(data["frames"], float(data["fps"]), joints=joints, style_id=data.get("style_id"),
                             model=data.get("model"), timing_ms=dict(data.get("timing_ms") or {}),
                             reach=Reach.from_message(data))


def transition_bvh(state: ClientState, context: Any, target: Any, frames: int, style_id: str | None,
                   style_motion: Any, seed: int | None, deterministic: bool, model_name: str | None,
                   exact_arrival: bool | None, style_strength: float | None = None) -> Operation[str]:
    cuts = yield from cutter(state, model_name)
    body = transition_body(context, target, frames, style_id, style_motion, seed, deterministic, "bvh", model_name,
                           exact_arrival, cuts, style_strength)
    request = Request("POST", "/v1/transition", json=body)
    return (yield from with_style(state, request, style_id, model_name)).json()["bvh"]


def transition_body(context: Any, target: Any, frames: int, style_id: str | None, style_motion: Any, seed: int | None,
                    deterministic: bool, output: str, model_name: str | None, exact_arrival: bool | None = None,
                    cuts: Cutter | None = None, style_strength: float | None = None) -> dict[str, Any]:
    """The request; with ``cuts``, each motion cut to what the model reads (:mod:`rsmt_client.motion_cuts`)."""
    if (style_id is None) == (style_motion is None):
        raise ValueError("give exactly one of style_id or style")
    from rsmt_client.motion_cuts import Cutter

    cuts = cuts or Cutter(None)
    body: dict[str, Any] = {"context": cuts.context(motion_payload(context)), "frames": int(frames),
                            "deterministic": bool(deterministic), "output": output}
    body.update(target_field(target, cuts.target))
    if style_id is not None:
        body["style_id"] = style_id
    else:
        body["style"] = cuts.style(motion_payload(style_motion))
    if seed is not None:
        body["seed"] = int(seed)
    if model_name is not None:
        body["model"] = model_name
    if exact_arrival is not None:  # sent only when said (None: the server's default, exact for target_at only),
        body["exact_arrival"] = bool(exact_arrival)  # so older servers keep accepting the request
    if style_strength is not None:
        body["style_strength"] = float(style_strength)
    return body


def default_style_name(motion: Any) -> str:
    """A style's display name when none is given: the file's stem for a path, else ``"style"``."""
    if isinstance(motion, Path) or (isinstance(motion, str) and motion.lower().endswith(".bvh") and "\n" not in motion):
        return Path(motion).stem
    return "style"
