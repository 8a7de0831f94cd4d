"""``rsmt bundle database BUNDLE --from-data DATA``: build a bundle's motion database from a data set.

The database (:mod:`model.retrieval.database`) holds the compressed poses of the train split's locomotion takes,
each without its first and last frames, within a byte budget (``--budget-mb``, 10 by default: the most the data's
licence lets a bundle carry); it is written to ``BUNDLE/database.safetensors`` and ``database.json`` in place
(weights, config and styles untouched) and loads with the bundle. For example::

    rsmt bundle database model/default_bundle --from-data "$RSMT_DATA"
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def add_bundle_and_data(parser: Any) -> None:
    """BUNDLE, written in place, and the --from-data it is built from (``rsmt bundle database`` and
    ``gait-limits``)."""
    parser.add_argument("bundle", type=Path, metavar="BUNDLE")
    parser.add_argument("--from-data", type=Path, required=True, metavar="DATA",
                        help="the training data (folders separated by the path separator, as RSMT_DATA)")


def add_database_parser(bundle_actions: Any) -> None:
    """``database`` under ``rsmt bundle``."""
    d = bundle_actions.add_parser(
        "database", help="write the bundle's motion database (real locomotion poses, for motion matching)",
        description="Build the motion database of BUNDLE from the train split of a motion dataset: the compressed "
                    "poses of its locomotion takes (each without its first and last half second), every style and "
                    "content in turn, within --budget-mb. Writes BUNDLE/database.safetensors and database.json; "
                    "weights, config and styles are not touched.")
    add_bundle_and_data(d)
    d.add_argument("--budget-mb", type=float, default=10.0, help="the most the database may take (default 10 MB)")
    d.add_argument("--workers", type=int, default=1, help="processes that read the data the first time (default 1)")
    d.set_defaults(func=_database)


def _database(args: argparse.Namespace) -> int:
    from model.data.database_build import database_from_data
    from model.inference.bundle import Bundle

    if not 0 < args.budget_mb <= 10:
        raise ValueError(f"--budget-mb must be above 0 and at most 10 (the data's licence), not {args.budget_mb:g}")
    bundle = Bundle.load(args.bundle, styles=False)  # checks the folder is a bundle, gives its rig and fps
    db = database_from_data(args.from_data, bundle.config.fps, int(args.budget_mb * 1_000_000), args.workers)
    if list(db.skeleton.names) != list(bundle.skeleton.names):
        raise ValueError(f"{args.from_data} is on another rig than {args.bundle} ({len(db.skeleton.names)} joints "
                         f"from {db.skeleton.names[0]!r}); build the database from the bundle's own training data")
    path = db.save(args.bundle)
    print(json.dumps({"bundle": str(args.bundle), "file": str(path), **db.describe()}, indent=1))
    return 0
