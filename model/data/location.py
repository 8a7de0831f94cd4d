"""Where the training motion data lives: the ``RSMT_DATA`` setting and its default.

``RSMT_DATA`` names a folder of BVH takes (searched recursively), e.g. the unpacked
Bandai-Namco dataset. Without it, the folder that ``../shared/data/unpack.sh`` fills by default
(``~/.cache/rsmt-data/bandai-namco-motion-2``) is used when it is complete.
"""

from __future__ import annotations

import os
from pathlib import Path

ENV_VAR = "RSMT_DATA"
DEFAULT_UNPACKED = Path.home() / ".cache" / "rsmt-data" / "bandai-namco-motion-2"


def find_data_dir() -> Path | None:
    """The configured motion-data folder, or ``None`` when there is none."""
    value = os.environ.get(ENV_VAR)
    if value:
        path = Path(value).expanduser()
        return path if path.is_dir() else None
    if (DEFAULT_UNPACKED / ".complete").is_file():
        return DEFAULT_UNPACKED
    return None
