"""Where the training motion data lives and where its preprocessed cache goes: the ``RSMT_DATA`` and
``RSMT_CACHE`` settings and their defaults (the only place the model package reads the environment).

``RSMT_DATA`` names a folder of BVH takes (searched recursively), e.g. the unpacked
Bandai-Namco dataset. Without it, the folder that ``../shared/data/unpack.sh`` fills by default
(``~/.cache/rsmt-data/bandai-namco-motion-2``) is used when it is complete.
"""

from __future__ import annotations

import os
from pathlib import Path

ENV_VAR = "RSMT_DATA"
DEFAULT_UNPACKED = Path.home() / ".cache" / "rsmt-data" / "bandai-namco-motion-2"
CACHE_ENV = "RSMT_CACHE"
DEFAULT_CACHE_ROOT = Path.home() / ".cache" / "rsmt" / "preprocessed"


def find_data_dir() -> Path | None:
    """The configured motion-data folder, or ``None`` when there is none."""
    value = os.environ.get(ENV_VAR)
    if value:
        path = Path(value).expanduser()
        return path if path.is_dir() else None
    if (DEFAULT_UNPACKED / ".complete").is_file():
        return DEFAULT_UNPACKED
    return None


def require_data_dir(given: Path | None) -> Path:
    """``given`` (a ``--data`` option), else the configured folder; an error saying how to name one when neither is set."""
    data = given or find_data_dir()
    if data is None:
        raise FileNotFoundError("no data folder: pass --data DIR or set RSMT_DATA")
    return data


def cache_root() -> Path:
    """Where preprocessed-data caches live: ``$RSMT_CACHE`` or ``~/.cache/rsmt/preprocessed``."""
    value = os.environ.get(CACHE_ENV)
    return Path(value).expanduser() if value else DEFAULT_CACHE_ROOT
