"""``python -m tests.service.first_start``: how long a fresh server's first stream ``start`` takes against the
ones after it (stream setup runs on its own threads, which the warm-up starts and warms).

Starts ``rsmt serve`` (the working directory's code) ``--servers`` times; on each, once ready, opens one
WebSocket and sends ``--starts`` starts one after the other (each waits for ``started``; inline style, so each
runs style encoding and ``prepare`` on the setup lane), timing ``start`` sent to ``started`` received. Prints
JSON: the first start's times and the later ones' median, per server. Run from the repository root:

    python -m tests.service.first_start --bundle model/default_bundle --servers 3
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--bundle", type=Path, default=Path("model/default_bundle"))
    p.add_argument("--servers", type=int, default=3)
    p.add_argument("--starts", type=int, default=6)
    args = p.parse_args()

    from tests.service.conftest import bvh, walk
    from tests.service.server import Server
    from tests.service.wsclient import Ws, start_message

    serve = [sys.executable, "-c", "import sys; from rsmt_cli.main import main; sys.exit(main())", "serve"]
    runs = []
    for _ in range(args.servers):
        srv = Server(args.bundle, command=[*serve, "--host", "127.0.0.1", "--port", "{port}"]).start(timeout_s=300)
        try:
            ms = []
            with Ws(srv.ws) as ws:
                for i in range(args.starts):
                    # A different style clip each time: every start encodes its style, as the first one does.
                    msg = start_message(f"c{i}", 10, style=bvh(walk(30 + i)))
                    sent = time.monotonic()
                    ws.send(msg)
                    reply = ws.recv(timeout=60)
                    ms.append(round((time.monotonic() - sent) * 1e3, 1))
                    assert reply["type"] == "started", reply
                    ws.run({f"c{i}"}, timeout=60)
        finally:
            srv.stop()
        runs.append({"first_ms": ms[0], "later_median_ms": statistics.median(ms[1:]), "all_ms": ms})
    print(json.dumps({"bundle": str(args.bundle), "load_average": os.getloadavg(), "runs": runs}, indent=1))


if __name__ == "__main__":
    main()
