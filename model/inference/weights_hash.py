"""The version of a set of weights: a hash of the stored tensors (names, dtypes, shapes, bytes), not of the file.

safetensors writes its metadata in no fixed order, so the same weights saved twice differ as files;
hashing the tensors gives the same version for the same weights whatever the file looks like.
"""

from __future__ import annotations

import hashlib

import torch


def weights_hash(tensors: dict[str, torch.Tensor], salt: str = "") -> str:
    """16 hex digits of SHA-256 over ``salt`` and every tensor in name order."""
    digest = hashlib.sha256(salt.encode())
    for name in sorted(tensors):
        t = tensors[name].detach().cpu().contiguous().reshape(-1)  # 0-d tensors (BatchNorm counters) cannot be viewed as bytes
        digest.update(f"{name}:{t.dtype}:{tuple(t.shape)}".encode())
        digest.update(t.view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    return digest.hexdigest()[:16]
