"""Who a request acts as: the owner of the styles it registers and the turns it takes in the work queues (a
digest of its API key, never the key), and whether it is an admin. Torch-free: the auth middleware makes one."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

ANONYMOUS = ""  # the one owner when API keys are off


@dataclass(frozen=True)
class Caller:
    """The owner a request acts as (a digest of its API key, never the key) and whether it is an admin."""

    owner: str = ANONYMOUS
    admin: bool = False

    @classmethod
    def from_key(cls, key: str | None, admin: bool) -> Caller:
        if key is None:
            return cls(ANONYMOUS, admin)
        return cls(hashlib.sha256(key.encode()).hexdigest()[:32], admin)
