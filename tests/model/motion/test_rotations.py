"""Property tests for model.motion.rotations: every conversion round-trips."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from model.motion import rotations as R
from tests.model.motion.rotation_angle import quat_angle

ORDERS = ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"]
finite = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)


@st.composite
def quats(draw, n: int = 5) -> torch.Tensor:
    vals = draw(st.lists(st.tuples(finite, finite, finite, finite), min_size=n, max_size=n))
    q = torch.tensor(vals, dtype=torch.float64)
    q = q[q.norm(dim=-1) > 0.1]
    if len(q) == 0:
        q = torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=torch.float64)
    return R.quat_normalize(q)


def axis_matrix(axis: int, angle: torch.Tensor) -> torch.Tensor:
    """The rotation by ``angle`` about x, y or z (0, 1, 2), written out: the reference the Euler conversions meet."""
    c, s = torch.cos(angle), torch.sin(angle)
    one, zero = torch.ones_like(angle), torch.zeros_like(angle)
    rows = {0: [one, zero, zero, zero, c, -s, zero, s, c], 1: [c, zero, s, zero, one, zero, -s, zero, c],
            2: [c, -s, zero, s, c, zero, zero, zero, one]}[axis]
    return torch.stack(rows, dim=-1).reshape(*angle.shape, 3, 3)


def euler_to_matrix(angles: torch.Tensor, order: str) -> torch.Tensor:
    """Euler angles ``(..., 3)`` listed in ``order`` as the product of their three axis matrices (intrinsic)."""
    i, j, k = ("XYZ".index(a) for a in order)
    return axis_matrix(i, angles[..., 0]) @ axis_matrix(j, angles[..., 1]) @ axis_matrix(k, angles[..., 2])


def same_rotation(a: torch.Tensor, b: torch.Tensor, atol: float = 1e-9) -> bool:
    return torch.allclose(R.quat_canonical(a), R.quat_canonical(b), atol=atol) or bool(
        (quat_angle(a, b) < 1e-6).all()
    )


@given(quats())
def test_quat_matrix_round_trip(q):
    back = R.matrix_to_quat(R.quat_to_matrix(q))
    assert (quat_angle(q, back) < 1e-6).all()
    assert torch.allclose(back.norm(dim=-1), torch.ones(len(q), dtype=q.dtype))
    assert (back[:, 3] >= 0).all()


@given(quats())
def test_matrix_is_orthonormal(q):
    m = R.quat_to_matrix(q)
    eye = torch.eye(3, dtype=q.dtype).expand_as(m)
    assert torch.allclose(m @ m.transpose(-1, -2), eye, atol=1e-9)
    assert torch.allclose(torch.det(m), torch.ones(len(q), dtype=q.dtype), atol=1e-9)


@given(quats())
def test_sixd_round_trip(q):
    m = R.quat_to_matrix(q)
    assert torch.allclose(R.sixd_to_matrix(R.matrix_to_sixd(m)), m, atol=1e-9)
    assert (quat_angle(R.sixd_to_quat(R.quat_to_sixd(q)), q) < 1e-6).all()


@given(st.lists(finite, min_size=6, max_size=6))
def test_sixd_gram_schmidt_gives_a_rotation(vals):
    d = torch.tensor(vals, dtype=torch.float64)
    a1, a2 = d[:3], d[3:]
    if a1.norm() < 1e-3 or torch.linalg.cross(a1, a2).norm() < 1e-3:
        return  # degenerate input has no defined rotation
    m = R.sixd_to_matrix(d)
    assert torch.allclose(m @ m.T, torch.eye(3, dtype=d.dtype), atol=1e-9)
    assert math.isclose(torch.det(m).item(), 1.0, abs_tol=1e-9)
    # The first column keeps the first input direction.
    assert torch.allclose(m[:, 0], a1 / a1.norm(), atol=1e-9)


@pytest.mark.parametrize("order", ORDERS)
@given(st.lists(st.floats(-math.pi, math.pi), min_size=3, max_size=3))
def test_euler_round_trip(order, angles):
    a = torch.tensor(angles, dtype=torch.float64)
    m = euler_to_matrix(a, order)
    q = R.euler_to_quat(a, order)
    assert torch.allclose(R.quat_to_matrix(q), m, atol=1e-9)
    back = R.matrix_to_euler(m, order)
    assert torch.allclose(euler_to_matrix(back, order), m, atol=1e-8)
    assert -math.pi / 2 - 1e-9 <= back[1].item() <= math.pi / 2 + 1e-9
    if abs(abs(angles[1]) - math.pi / 2) > 1e-3 and abs(angles[1]) < math.pi / 2:
        assert torch.allclose(back, a, atol=1e-7)


@pytest.mark.parametrize("order", ORDERS)
def test_euler_gimbal_lock(order):
    a = torch.tensor([0.3, math.pi / 2, -0.4], dtype=torch.float64)
    m = euler_to_matrix(a, order)
    back = R.matrix_to_euler(m, order)
    assert torch.allclose(euler_to_matrix(back, order), m, atol=1e-7)


def test_euler_order_convention_is_intrinsic_product():
    a = torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)
    rz, rx, ry = (axis_matrix(axis, torch.tensor(angle, dtype=torch.float64)) for axis, angle in ((2, 0.1), (0, 0.2), (1, 0.3)))
    assert torch.allclose(R.quat_to_matrix(R.euler_to_quat(a, "ZXY")), rz @ rx @ ry, atol=1e-12)


def test_bad_euler_order():
    with pytest.raises(ValueError, match="order"):
        R.euler_to_quat(torch.zeros(3), "XXY")


@given(quats(), quats())
def test_mul_matches_matrix_product(a, b):
    n = min(len(a), len(b))
    a, b = a[:n], b[:n]
    assert torch.allclose(R.quat_to_matrix(R.quat_mul(a, b)), R.quat_to_matrix(a) @ R.quat_to_matrix(b), atol=1e-9)


def test_mul_broadcasts_and_keeps_dtype():
    a = R.quat_normalize(torch.randn(5, 3, 4, dtype=torch.float64))
    b = R.quat_normalize(torch.randn(3, 4, dtype=torch.float64))
    out = R.quat_mul(a, b)
    assert out.shape == (5, 3, 4) and out.dtype == torch.float64
    assert torch.allclose(R.quat_mul(a[2, 1], b[1]), out[2, 1])
    assert R.quat_mul(a.float(), b.float()).dtype == torch.float32


def test_mul_first_used_in_inference_mode_still_trains():
    # The product's constant table is cached per dtype; one made inside inference mode would break backward.
    dtype = torch.float64
    R._hamilton_tables.pop((dtype, torch.device("cpu")), None)
    with torch.inference_mode():
        R.quat_mul(torch.randn(2, 4, dtype=dtype), torch.randn(2, 4, dtype=dtype))
    a = torch.randn(3, 4, dtype=dtype, requires_grad=True)
    R.quat_mul(a, a.detach()).sum().backward()
    assert a.grad is not None and torch.isfinite(a.grad).all()


@given(quats(), st.lists(finite, min_size=3, max_size=3))
def test_rotate_matches_matrix(q, v):
    vec = torch.tensor(v, dtype=torch.float64).expand(len(q), 3)
    expected = (R.quat_to_matrix(q) @ vec.unsqueeze(-1)).squeeze(-1)
    assert torch.allclose(R.quat_rotate(q, vec), expected, atol=1e-9)
    # Broadcasting one quaternion over many vectors.
    many = R.quat_rotate(q[:1], vec)
    assert torch.allclose(many, (R.quat_to_matrix(q[:1]) @ vec.unsqueeze(-1)).squeeze(-1), atol=1e-9)


@given(quats())
def test_inverse(q):
    ident = R.quat_mul(q, R.quat_conjugate(q))
    assert torch.allclose(R.quat_canonical(ident), R.quat_identity((len(q),), torch.float64), atol=1e-9)


@given(quats(), quats(), st.floats(0.0, 1.0))
def test_slerp(a, b, t):
    n = min(len(a), len(b))
    a, b = a[:n], b[:n]
    assert (quat_angle(R.quat_slerp(a, b, 0.0), a) < 1e-6).all()
    assert (quat_angle(R.quat_slerp(a, b, 1.0), b) < 1e-6).all()
    total = quat_angle(a, b)
    part = quat_angle(a, R.quat_slerp(a, b, t))
    assert torch.allclose(part, t * total, atol=1e-5)


def test_slerp_per_element_t():
    a = R.quat_identity((3,), torch.float64)
    b = R.axis_angle_to_quat(torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64).expand(3, 3),
                             torch.full((3,), 1.0, dtype=torch.float64))
    t = torch.tensor([0.0, 0.5, 1.0], dtype=torch.float64)
    out = R.quat_slerp(a, b, t)
    assert torch.allclose(quat_angle(a, out), t, atol=1e-9)


def test_make_continuous():
    q = R.quat_normalize(torch.randn(20, 4, dtype=torch.float64))
    flipped = q * torch.where(torch.rand(20, 1) < 0.5, -1.0, 1.0).double()
    cont = R.quat_make_continuous(flipped)
    assert ((cont[1:] * cont[:-1]).sum(-1) >= 0).all()
    assert (quat_angle(cont, q) < 1e-6).all()


def test_yaw_quat_turns_z_to_x():
    q = R.yaw_quat(torch.tensor(math.pi / 2, dtype=torch.float64))
    z = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    assert torch.allclose(R.quat_rotate(q, z), torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64), atol=1e-12)


def test_batched_equals_single():
    q = R.quat_normalize(torch.randn(4, 7, 4, dtype=torch.float64))
    whole = R.quat_to_sixd(q)
    for i in range(4):
        assert torch.allclose(whole[i], R.quat_to_sixd(q[i]))
