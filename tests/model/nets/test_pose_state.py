"""integrate: one normalisation for every joint, the imposed root's included, gives what normalising it apart did."""

from __future__ import annotations

import torch

from model.motion.rotations import sixd_normalize
from model.nets.pose_state import PoseState, integrate


def test_an_imposed_root_rotation_is_normalised_with_the_others_to_the_same_bits() -> None:
    gen = torch.Generator().manual_seed(3)
    n, j, root = 4, 7, 2
    state = PoseState(torch.randn(n, j, 3, generator=gen), torch.randn(n, j, 3, generator=gen),
                      sixd_normalize(torch.randn(n, j, 6, generator=gen)), torch.randn(n, 2, generator=gen))
    vel, delta = torch.randn(n, j, 3, generator=gen), 0.1 * torch.randn(n, j, 6, generator=gen)
    imposed = torch.randn(n, 6, generator=gen)
    got = integrate(state, vel, delta, root=root, root_rotation=imposed)
    free = integrate(state, vel, delta, root=root)
    # What the decoder did before: normalise every joint, then put the imposed root, normalised on its own, in place.
    want = torch.cat([free.rot[:, :root], sixd_normalize(imposed).unsqueeze(1), free.rot[:, root + 1:]], dim=1)
    assert torch.equal(got.rot, want)
    assert torch.equal(got.rel, free.rel) and torch.equal(got.vel, free.vel) and torch.equal(got.root_xz, free.root_xz)
    assert not torch.equal(got.rot[:, root], free.rot[:, root])
