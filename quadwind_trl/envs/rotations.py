"""Batched rotation helpers. Quaternions are ``(w, x, y, z)``, unit, rotating body to world."""
from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor

from .operands import operands


class _Tables(NamedTuple):
    """Index and sign tables that let :func:`quat_mul` and :func:`quat_to_rotmat` evaluate their
    textbook expressions four or nine entries per operation, with the same roundings (``a - b``
    is ``a + (-1) b`` and ``2 s`` is ``s + s``, exactly): a dozen eager ops instead of thirty;
    and the numbers :func:`quat_integrate` and :func:`body_z_vertical` combine, as tensors for
    the eager step (:mod:`.operands`)."""

    mul_index: Tensor  # quat_mul: terms 1-3 of each component in the outer product a b^T
    mul_sign: Tensor
    rotmat_a: Tensor  # quat_to_rotmat: R_ij = 2 (P[a] + sign P[b]) (1 minus that on the
    rotmat_b: Tensor  # diagonal), P the outer product q q^T
    rotmat_sign: Tensor
    diagonal: Tensor
    one: Tensor
    sinc_series_below: Tensor  # quat_integrate: the angle below which sin(x)/x is its Taylor series
    six: Tensor


_TABLES: dict[tuple[torch.device, torch.dtype], _Tables] = {}


def _tables(device: torch.device, dtype: torch.dtype) -> _Tables:
    """The tables on ``device``, signs in ``dtype``, made once (the simulator's first ones by its
    eager ``initial``, before any compiled step)."""
    key = (device, dtype)
    if key not in _TABLES:
        index = lambda v: torch.tensor(v, device=device)  # noqa: E731
        sign = lambda v: torch.tensor(v, dtype=dtype, device=device)  # noqa: E731
        # flattened outer products, (w, x, y, z) = 0 .. 3: entry 4 i + j is a_i b_j
        _TABLES[key] = _Tables(
            mul_index=index([5, 4, 7, 6, 10, 11, 8, 9, 15, 14, 13, 12]),
            mul_sign=sign([-1.0, 1.0, -1.0, 1.0, -1.0, 1.0, 1.0, -1.0, -1.0, -1.0, 1.0, 1.0]),
            # R_00 = 1 - 2 (yy + zz), R_01 = 2 (xy - wz), ...: row-major
            rotmat_a=index([10, 6, 7, 6, 5, 11, 7, 11, 5]),
            rotmat_b=index([15, 3, 2, 3, 15, 1, 2, 1, 10]),
            rotmat_sign=sign([1.0, -1.0, 1.0, 1.0, 1.0, -1.0, -1.0, 1.0, 1.0]),
            diagonal=index([True, False, False, False, True, False, False, False, True]),
            one=sign(1.0),
            sinc_series_below=sign(1e-4),
            six=sign(6.0),
        )
    return _TABLES[key]


def quat_mul(a: Tensor, b: Tensor) -> Tensor:
    """The Hamilton product, each component ``a_w b_. + term1 + term2 + term3`` summed in that
    order (``w = aw bw - ax bx - ay by - az bz``, ...)."""
    t = _tables(a.device, a.dtype)
    outer = a.unsqueeze(-1) * b.unsqueeze(-2)
    term1, term2, term3 = (outer.flatten(-2).index_select(-1, t.mul_index) * t.mul_sign).unflatten(-1, (3, 4)).unbind(-2)
    return ((outer[..., 0, :] + term1) + term2) + term3


def quat_to_rotmat(q: Tensor) -> Tensor:
    """``[..., 3, 3]`` matrix ``R`` with ``v_world = R @ v_body``; its columns are the body axes."""
    t = _tables(q.device, q.dtype)
    products = (q.unsqueeze(-1) * q.unsqueeze(-2)).flatten(-2)
    half = products.index_select(-1, t.rotmat_a) + products.index_select(-1, t.rotmat_b) * t.rotmat_sign
    twice = half + half
    return torch.where(t.diagonal, t.one - twice, twice).unflatten(-1, (3, 3))


def body_z_vertical(q: Tensor) -> Tensor:
    """``[..., 1]``: ``quat_to_rotmat(q)[..., 2, 2:3]``, the vertical component of the body z axis
    (``1 - 2 (xx + yy)``, the same bits), without the other eight entries."""
    xy = q[..., 1:3]
    squares = xy * xy
    half = squares[..., :1] + squares[..., 1:]
    return operands(_tables(q.device, q.dtype).one, 1.0) - (half + half)


def quat_from_euler(roll: Tensor, pitch: Tensor, yaw: Tensor) -> Tensor:
    """Z-Y-X (yaw, then pitch, then roll) Euler angles in radians to a quaternion."""
    cr, sr = torch.cos(roll / 2), torch.sin(roll / 2)
    cp, sp = torch.cos(pitch / 2), torch.sin(pitch / 2)
    cy, sy = torch.cos(yaw / 2), torch.sin(yaw / 2)
    return torch.stack(
        (
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ),
        -1,
    )


def atan2(y: Tensor, x: Tensor) -> Tensor:
    """``atan2`` built on ``atan``: ATen's CPU ``atan2`` rounds a tensor's vectorised body and
    its scalar tail differently, so a row's result would depend on its place in the batch;
    ``atan`` does not (checked), which keeps replay bitwise whatever the batch."""
    base = torch.atan(y / torch.where(x == 0, 1.0, x))
    shifted = torch.where(y >= 0, base + math.pi, base - math.pi)
    on_axis = torch.where(y > 0, math.pi / 2, torch.where(y < 0, -math.pi / 2, 0.0))
    return torch.where(x > 0, base, torch.where(x < 0, shifted, on_axis))


def euler_from_rotmat(r: Tensor) -> Tensor:
    """``[..., 3]`` Z-Y-X Euler angles (roll, pitch, yaw) in radians."""
    # roll and yaw in one atan2 of two columns: elementwise, and its atan rounds an element the
    # same wherever it sits in a tensor
    roll, yaw = atan2(torch.stack((r[..., 2, 1], r[..., 1, 0]), -1), torch.stack((r[..., 2, 2], r[..., 0, 0]), -1)).unbind(-1)
    pitch = torch.asin(torch.clamp(-r[..., 2, 0], -1.0, 1.0))
    return torch.stack((roll, pitch, yaw), -1)


def quat_integrate(q: Tensor, omega_body: Tensor, half_dt: Tensor | float) -> Tensor:
    """Rotate ``q`` by a constant body rate over ``2 half_dt`` (exact exponential map),
    renormalised. ``half_dt``: half the step, a number or (for an eager caller that steps often:
    no conversion per use) a 0-dim tensor of the rate's dtype."""
    t = _tables(q.device, q.dtype)
    series_below, one, six = operands((t.sinc_series_below, t.one, t.six), (1e-4, 1.0, 6.0))
    half_angle = half_dt * omega_body
    theta = norm(half_angle)
    # sin(theta)/theta, with its Taylor series where theta is tiny (no division by zero)
    sinc = torch.where(theta < series_below, one - theta * theta / six, torch.sin(theta) / theta.clamp_min(1e-12))
    dq = torch.cat((torch.cos(theta), sinc * half_angle), -1)
    out = quat_mul(q, dq)
    return out / norm(out)


# Small products as broadcast multiply-and-sum rather than ``@``: as fast for 3x3 and 4x4, fused
# by torch.compile, and free of BLAS's size-dependent kernel choice, so a row's result does not
# depend on how many rows share its batch (bitwise replay).


def matvec(m: Tensor, v: Tensor) -> Tensor:
    """``m @ v`` over the last two/one dims, batch-size independent."""
    return (m * v.unsqueeze(-2)).sum(-1)


def vecmat(v: Tensor, m: Tensor) -> Tensor:
    """``v @ m`` (``v`` ``[..., K]``, ``m`` ``[..., K, J]``), batch-size independent."""
    return (v.unsqueeze(-1) * m).sum(-2)


def matmul(a: Tensor, b: Tensor) -> Tensor:
    """``a @ b`` for batches of small matrices, batch-size independent."""
    return (a.unsqueeze(-1) * b.unsqueeze(-3)).sum(-2)


def norm(v: Tensor) -> Tensor:
    """``v.norm(dim=-1, keepdim=True)``: the kernel ``Tensor.norm`` calls, without its Python
    dispatch (as long as an eager op on a small batch)."""
    return torch.linalg.vector_norm(v, dim=-1, keepdim=True)


def rotate(r: Tensor, v: Tensor) -> Tensor:
    """``R @ v`` for batches of matrices and vectors."""
    return matvec(r, v)


def rotate_inverse(r: Tensor, v: Tensor) -> Tensor:
    """``R^T @ v``."""
    return vecmat(v, r)


def vee(m: Tensor) -> Tensor:
    """The vector of a skew-symmetric matrix."""
    return torch.stack((m[..., 2, 1], m[..., 0, 2], m[..., 1, 0]), -1)
