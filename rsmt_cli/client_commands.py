"""The ``rsmt client`` commands: talk to a running service with the Python client (``rsmt_client``).

    rsmt client styles add clip.bvh [--name N] [--start S --frames N]
    rsmt client styles list                 (the models' built-in styles, then yours)
    rsmt client transition --context a.bvh --target b.bvh --frames 40 --style ID -o out.bvh [--seed S]
    rsmt client transition --context a.bvh --target-at 120,300,90 --frames 40 --style ID   (a place and facing)
    rsmt client stream --context a.bvh --target b.bvh --frames 40 --style ID [--binary] [-o out.bvh]
    rsmt client demo [NAME --out walk.bvh]   (the viewer's demo takes: motion on the model's rig, as BVH)

Every command takes ``--url`` (default http://127.0.0.1:8000, or $RSMT_URL) and ``--api-key``
(or $RSMT_API_KEY). Results print as JSON lines on stdout; errors print the server's code and
message on stderr and exit with 1. ``transition`` and ``stream`` also say on stderr whether the target was within
reach at the style's capture speed (their JSON carries the notice as ``reach``); ``stream`` ends with "arrived" or
"stopped short ... cm short".
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any, cast


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--url", default=os.environ.get("RSMT_URL", "http://127.0.0.1:8000"),
                        help="service base URL (default $RSMT_URL or http://127.0.0.1:8000)")
    parser.add_argument("--api-key", default=os.environ.get("RSMT_API_KEY"),
                        help="API key, sent as X-API-Key (default $RSMT_API_KEY)")
    parser.add_argument("--retries", type=int, default=5,
                        help="tries per request on 429/503/refused connections, with backoff (default 5; 1: none)")
    parser.add_argument("--timeout", type=float, default=60.0, help="seconds per request (default 60)")


def _motion_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--context", type=Path, required=True, metavar="BVH",
                        help="the character's recent motion (at least the model's context_frames frames; a whole take "
                             "is cut to the last of them)")
    target = parser.add_mutually_exclusive_group(required=True)
    target.add_argument("--target", type=Path, metavar="BVH",
                        help="the target: its last frame is the pose to arrive at (a whole take is cut to its last two)")
    target.add_argument("--target-at", type=_place, metavar="X,Z,YAW",
                        help="the target as a place and facing instead: the root arrives over X,Z (model units) facing "
                             "YAW degrees about +Y (0: +Z, 90: +X), in the context's last pose, exactly (a negative X: "
                             "--target-at=-50,300,90)")
    parser.add_argument("--frames", type=int, required=True, help="frames to generate (the last one arrives)")
    parser.add_argument("--style", required=True, metavar="ID|BVH",
                        help="a style_id from `rsmt client styles add` or builtin:NAME, or a style clip .bvh (sent "
                             "with the request; `stream` registers it over HTTP first; a clip longer than the model "
                             "reads is cut to its middle, said on stderr)")
    parser.add_argument("--seed", type=int, help="sampling seed (same inputs + seed give the same frames)")
    parser.add_argument("--deterministic", action="store_true", help="no sampling noise")
    parser.add_argument("--exact-arrival", action=argparse.BooleanOptionalAction, default=None,
                        help="bend the last frames so the arrival frame equals the target pose (default: the server's, "
                        "exact for --at only; --no-exact-arrival leaves an --at target the network's own arrival)")
    parser.add_argument("-o", "--out", type=Path, metavar="BVH", help="write the generated frames as BVH")


def _place(text: str) -> Any:
    from rsmt_client import TargetAt

    try:
        return TargetAt.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _target(args: argparse.Namespace) -> Any:
    """``--target-at``'s place, else ``--target``'s BVH as a Motion."""
    from rsmt_client import read_bvh

    return args.target_at if args.target_at is not None else {"bvh": read_bvh(args.target)}


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("client", help="use a running service (styles, transitions, streams)",
                              description="Talk to a running RSMT service with the Python client.")
    sub = p.add_subparsers(dest="client_command", required=True, metavar="SUBCOMMAND")

    styles = sub.add_parser("styles", help="register and list style clips")
    ssub = styles.add_subparsers(dest="styles_command", required=True, metavar="ACTION")
    add = ssub.add_parser("add", help="register a style clip (BVH), or 2 to 5 clips of one style as one style; "
                                      "prints its style_id")
    add.add_argument("clip", type=Path, help="style clip .bvh")
    add.add_argument("more", type=Path, nargs="*", metavar="CLIP",
                     help="more clips of the same style (up to 5 in all), encoded together with the first into one "
                          "style; their order does not change it")
    add.add_argument("--name", help="display name (default: the file name)")
    add.add_argument("--model", help="model to encode for (default: the server's default)")
    add.add_argument("--start", type=int, default=0, metavar="S",
                     help="first frame of the clip to send (the file's own frame numbering, from 0; default 0)")
    add.add_argument("--frames", type=int, metavar="N",
                     help="frames to send from --start (the file's own frames; default: to the end). A style clip "
                          "must hold the model's style_clip_frames (GET /v1/model) at the model's fps")
    _common(add)
    add.set_defaults(func=_styles_add)
    ls = ssub.add_parser("list", help="list the models' built-in styles (builtin:NAME) and the ones you registered")
    ls.add_argument("--json", action="store_true", help="one JSON object per line instead of a table")
    _common(ls)
    ls.set_defaults(func=_styles_list)

    tr = sub.add_parser("transition", help="one whole transition over HTTP (POST /v1/transition)")
    _motion_args(tr)
    _common(tr)
    tr.set_defaults(func=_transition)

    st = sub.add_parser("stream", help="a transition streamed frame by frame over the WebSocket")
    _motion_args(st)
    st.add_argument("--binary", action="store_true", help="binary float32 frames instead of JSON")
    st.add_argument("--pace", choices=["realtime", "asap"], default="realtime",
                    help="realtime: frames at the model fps (default); asap: as fast as generated")
    st.add_argument("--quiet", action="store_true", help="no line per frame")
    _common(st)
    st.set_defaults(func=_stream)

    demo = sub.add_parser("demo", help="write one of the viewer's demo takes as BVH (motion on the model's rig), "
                                       "or list them",
                          description="The web viewer's demo takes: on the default model, walks it generates itself "
                                      "from a standing pose in each built-in style (walk-normal, walk-elderly-turn-left, "
                                      "...). Without NAME: list them.")
    demo.add_argument("name", nargs="?", help="the demo take (default: list them)")
    demo.add_argument("-o", "--out", type=Path, metavar="BVH", help="where to write it (default NAME.bvh)")
    demo.add_argument("--model", help="the model (default: the server's default)")
    _common(demo)
    demo.set_defaults(func=_demo)


def _skip_httpx_cli() -> None:
    """Keep httpx from importing its own command-line tool. Where click, rich and pygments are installed (the
    service's environment has them) ``import httpx`` loads them for ``httpx.main``, which these commands never
    call: about a third of a client command's start-up. Done only in this process, before httpx loads;
    ``httpx.main`` then says its dependencies are missing."""
    if "httpx" not in sys.modules:
        # None in sys.modules makes an import of that name fail (Python's import system documents it).
        cast(dict[str, ModuleType | None], sys.modules).setdefault("httpx._main", None)


def _retry(args: argparse.Namespace) -> Any:
    from rsmt_client import RetryPolicy

    return RetryPolicy(attempts=max(1, args.retries))


def _client(args: argparse.Namespace) -> Any:
    from rsmt_client import Client

    return Client(args.url, api_key=args.api_key, timeout=args.timeout, retry=_retry(args))


def _style_choice(value: str) -> dict[str, Any]:
    from rsmt_client import read_bvh

    path = Path(value)
    if value.lower().endswith(".bvh") or path.is_file():
        return {"style": {"bvh": read_bvh(path)}}
    return {"style_id": value}


def _print(obj: Any) -> None:
    print(json.dumps(obj, separators=(", ", ": ")), flush=True)


def _reach_fields(reach: Any) -> dict[str, Any] | None:
    """The reach notice (``rsmt_client.Reach``) as the JSON summary carries it (None: the model said nothing)."""
    return None if reach is None else dataclasses.asdict(reach)


def _reach_line(reach: Any) -> str:
    """What the reach notice says, for stderr: within reach or not, the distance, what is reachable, the frames."""
    if reach is None:
        return "reach: not said (the model has no gait limits)"
    said = "within reach" if reach.feasible else "out of reach"
    return (f"reach: {said}: {reach.distance_cm:.1f} cm away, {reach.reachable_cm:.1f} cm reachable in "
            f"{reach.frames} frames at the style's top speed {reach.max_speed_cm_s:.1f} cm/s "
            f"({reach.needed_frames} frames needed)")


def _end_line(reason: str | None, reach: Any) -> str:
    """How a streamed character ended: arrived, stopped short (its last target out of reach) or cancelled."""
    if reason != "arrived":
        return f"ended: {reason}"
    if reach is not None and not reach.feasible:
        return (f"stopped short: {reach.short_cm:.1f} cm short of the target ({reach.distance_cm:.1f} cm away, "
                f"{reach.reachable_cm:.1f} cm reachable in {reach.frames} frames; ask for {reach.needed_frames})")
    return "arrived"


def _guard(fn: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """``fn`` with the service's errors printed (code and message) and exit status 1."""

    def run(args: argparse.Namespace) -> int:
        _skip_httpx_cli()
        from rsmt_client import RsmtError

        try:
            return fn(args)
        except RsmtError as exc:
            print(f"rsmt client: {exc}", file=sys.stderr)
            return 1
    return run


@_guard
def _styles_add(args: argparse.Namespace) -> int:
    from rsmt_client.bvh import BvhFile

    clip: Path | str = args.clip
    if args.more:
        if args.start or args.frames is not None:
            raise ValueError("--start and --frames cut one clip; cut each of several clips before registering them")
        with _client(args) as c:
            _print(c.register_style_clips([args.clip, *args.more], name=args.name or args.clip.stem, model=args.model))
        return 0
    if args.start or args.frames is not None:
        # Checked here, before any request: an out-of-range cut is this command's error (exit 2), with the
        # file's frame count in the message.
        clip = BvhFile.read(args.clip).window(args.start, args.frames).format(precision=None)
    with _client(args) as c:
        _print(c.register_style(clip, name=args.name or args.clip.stem, model=args.model))
    return 0


@_guard
def _styles_list(args: argparse.Namespace) -> int:
    with _client(args) as c:
        styles = c.styles()
    if args.json:
        for s in styles:
            _print(s)
        return 0
    print(f"{'style_id':<40} {'frames':>6}  {'model':<16} {'kind':<10} name")
    for s in styles:
        kind = "built-in" if s.get("builtin") else "registered"
        print(f"{s['style_id']:<40} {s['frames']:>6}  {s.get('model', ''):<16} {kind:<10} {s['name']}")
    return 0


@_guard
def _transition(args: argparse.Namespace) -> int:
    from rsmt_client import read_bvh

    context, target = {"bvh": read_bvh(args.context)}, _target(args)
    with _client(args) as c:
        poses = c.transition(context, target, args.frames, seed=args.seed, deterministic=args.deterministic,
                             exact_arrival=args.exact_arrival, **_style_choice(args.style))
        summary: dict[str, Any] = {"frames": poses.num_frames, "fps": poses.fps, "style_id": poses.style_id,
                                   "model": poses.model, "timing_ms": poses.timing_ms,
                                   "reach": _reach_fields(poses.reach)}
        print(_reach_line(poses.reach), file=sys.stderr, flush=True)
        if args.out:
            poses.save_bvh(args.out, c.model())
            summary["out"] = str(args.out)
        else:
            summary["root_positions"] = poses.root_positions.tolist()
    _print(summary)
    return 0


@_guard
def _stream(args: argparse.Namespace) -> int:
    from rsmt_client import StreamClient, read_bvh

    context, target = {"bvh": read_bvh(args.context)}, _target(args)
    style = _style_choice(args.style)
    if "style" in style:
        # A style clip of a few seconds is larger than a WebSocket message may be (64 KiB by default):
        # register it over HTTP once and stream with its id.
        with _client(args) as c:
            style = {"style_id": c.register_style(Path(args.style), name=Path(args.style).stem)["style_id"]}

    def show(_client: Any, f: Any) -> None:
        if not args.quiet:
            _print({"type": "frame", "seq": f.seq, "t": round(f.t, 6), "remaining": f.remaining,
                    "root_position": [round(float(v), 4) for v in f.root_position]})

    with StreamClient(args.url, api_key=args.api_key, encoding="binary" if args.binary else "json",
                      retry=_retry(args), open_timeout=args.timeout) as s:
        character = s.start(context, target, args.frames, seed=args.seed, deterministic=args.deterministic,
                            pace=args.pace, exact_arrival=args.exact_arrival, **style)
        result = s.collect(character, timeout=args.timeout + args.frames / float(s.model["fps"]), on_frame=show)
        reason = (result.end or {}).get("reason")
        summary: dict[str, Any] = {"type": "end", "character": character, "frames": len(result.frames),
                                   "reason": reason, "encoding": s.encoding, "reach": _reach_fields(result.reach),
                                   "stopped_short": reason == "arrived" and result.stopped_short}
        if args.out:
            result.poses(s.joint_names).save_bvh(args.out, s.model)
            summary["out"] = str(args.out)
    _print(summary)
    print(_reach_line(result.reach), file=sys.stderr, flush=True)
    print(_end_line(reason, result.reach), file=sys.stderr, flush=True)
    return 0


@_guard
def _demo(args: argparse.Namespace) -> int:
    with _client(args) as c:
        if args.name is None:
            for d in c.demos(args.model):
                print(f"{d['name']:<28} {d['description']}")
            return 0
        poses = c.demo(args.name, args.model)
        out = args.out or Path(f"{args.name}.bvh")
        poses.save_bvh(out, c.model(args.model))
    _print({"out": str(out), "frames": poses.num_frames, "fps": poses.fps, "model": poses.model})
    return 0
