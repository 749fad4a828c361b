"""Batched rotation helpers. Quaternions are ``(w, x, y, z)``, unit, rotating body to world."""
from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor

from .operands import operands, tracing


class _Tables(NamedTuple):
    """Index and sign tables that let :func:`quat_mul`, :func:`quat_to_rotmat` and
    :func:`euler_to_rotmat` evaluate their textbook expressions four or nine entries per op (a
    handful of eager ops, not dozens, and no more arithmetic than the expressions have), and the
    numbers :func:`quat_integrate` and :func:`body_z_vertical` combine, as tensors for the eager
    step (:mod:`.operands`).

    Traced, the same functions write the expressions out entry by entry instead: inductor fuses
    them into the step's elementwise kernels, where a table is one more kernel input read through
    an index (an indirect load per entry, and a small reduction for ``vecdot``). Traced with the
    tables, the compiled step at N = 4096 took 1.2-1.3x the CPU time it takes written out
    (``bench/env_throughput.py --compile 1``; docs/benchmarks.md). Eager and traced forms agree to
    the last bit or two (the same products, summed in another order)."""

    mul_index: Tensor  # [16]: quat_mul's matrix L(a) (a b = L(a) b), row-major, as components of a
    mul_sign: Tensor  # [16]: and their signs
    rotmat_left: Tensor  # [18]: quat_to_rotmat's products q_l q_r, the first of each entry's two
    rotmat_right: Tensor  # [18]    terms (9), then the second (9)
    rotmat_sign: Tensor  # [9]: the second term's sign
    rotmat_minus_diagonal: Tensor  # [9]: -1 on the diagonal
    euler_index: Tensor  # [2 * 9 * 3]: euler_to_rotmat's factors, of (cos, sin) of the angles and 1
    euler_sign: Tensor  # [2, 9]: the sign of each entry's two products
    vee_map: Tensor  # [3, 9]: vee_antisymmetric's weights of the entries m_ij (column 3 i + j)
    one: Tensor
    two: Tensor
    inv_pi: Tensor  # quat_integrate: sin(x) / x is torch.sinc(x / pi)


_TABLES: dict[tuple[torch.device, torch.dtype], _Tables] = {}

# (w, x, y, z) = 0 .. 3. The Hamilton product a b = L(a) b, row c of L(a) the signed components
# of a that multiply (bw, bx, by, bz) in component c: w = aw bw - ax bx - ay by - az bz, ...
_HAMILTON = (
    ((0, 1), (1, -1), (2, -1), (3, -1)),
    ((1, 1), (0, 1), (3, -1), (2, 1)),
    ((2, 1), (3, 1), (0, 1), (1, -1)),
    ((3, 1), (2, -1), (1, 1), (0, 1)),
)
# R of a unit quaternion, row-major, each entry 2 (q_a q_b +- q_c q_d), minus 1 on the diagonal
# (R_00 = 1 - 2 (yy + zz) = 2 (ww + xx) - 1): ((a, b), (c, d), sign)
_ROTMAT = (
    ((0, 0), (1, 1), 1), ((1, 2), (0, 3), -1), ((1, 3), (0, 2), 1),
    ((1, 2), (0, 3), 1), ((0, 0), (2, 2), 1), ((2, 3), (0, 1), -1),
    ((1, 3), (0, 2), -1), ((2, 3), (0, 1), 1), ((0, 0), (3, 3), 1),
)
# R = Rz(yaw) Ry(pitch) Rx(roll), row-major, each entry a signed sum of two products of three of
# (cr, cp, cy, sr, sp, sy, 1) = 0 .. 6: R_00 = cy cp, R_01 = cy sp sr - sy cr, ...; an entry of
# one product has a second of sign 0
_EULER = (
    (((2, 1, 6), 1), ((6, 6, 6), 0)), (((2, 4, 3), 1), ((5, 0, 6), -1)), (((2, 4, 0), 1), ((5, 3, 6), 1)),
    (((5, 1, 6), 1), ((6, 6, 6), 0)), (((5, 4, 3), 1), ((2, 0, 6), 1)), (((5, 4, 0), 1), ((2, 3, 6), -1)),
    (((4, 6, 6), -1), ((6, 6, 6), 0)), (((1, 3, 6), 1), ((6, 6, 6), 0)), (((1, 0, 6), 1), ((6, 6, 6), 0)),
)


def _tables(device: torch.device, dtype: torch.dtype) -> _Tables:
    """The tables on ``device``, signs in ``dtype``, made once (the simulator's first ones by its
    eager ``initial``, before any compiled step)."""
    key = (device, dtype)
    if key not in _TABLES:
        index = lambda v: torch.tensor(v, device=device)  # noqa: E731
        sign = lambda v: torch.tensor(v, dtype=dtype, device=device)  # noqa: E731
        terms = [term for entry in _ROTMAT for term in entry[:2]]
        _TABLES[key] = _Tables(
            mul_index=index([i for row in _HAMILTON for i, _ in row]),
            mul_sign=sign([float(s) for row in _HAMILTON for _, s in row]),
            rotmat_left=index([t[0] for t in terms[0::2] + terms[1::2]]),
            rotmat_right=index([t[1] for t in terms[0::2] + terms[1::2]]),
            rotmat_sign=sign([float(e[2]) for e in _ROTMAT]),
            rotmat_minus_diagonal=sign([-1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0]),
            # [product, entry, factor], flattened
            euler_index=index([_EULER[e][t][0][f] for t in range(2) for e in range(9) for f in range(3)]),
            euler_sign=sign([[float(_EULER[e][t][1]) for e in range(9)] for t in range(2)]),
            vee_map=sign([[0, 0, 0, 0, 0, 0.5, 0, -0.5, 0], [0, 0, -0.5, 0, 0, 0, 0.5, 0, 0],
                          [0, 0.5, 0, -0.5, 0, 0, 0, 0, 0]]),
            one=sign(1.0),
            two=sign(2.0),
            inv_pi=sign(1.0 / math.pi),
        )
    return _TABLES[key]


def quat_mul(a: Tensor, b: Tensor) -> Tensor:
    """The Hamilton product (``w = aw bw - ax bx - ay by - az bz``, ...), as ``L(a) b``."""
    if tracing():
        aw, ax, ay, az = a.unbind(-1)
        bw, bx, by, bz = b.unbind(-1)
        return torch.stack((aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw), -1)
    t = _tables(a.device, a.dtype)
    left = (a.index_select(-1, t.mul_index) * t.mul_sign).unflatten(-1, (4, 4))
    return torch.linalg.vecdot(left, b.unsqueeze(-2))


def quat_to_rotmat(q: Tensor) -> Tensor:
    """``[..., 3, 3]`` matrix ``R`` with ``v_world = R @ v_body`` of a unit quaternion; its
    columns are the body axes."""
    if tracing():  # the same two terms per entry as the tables', written out
        w, x, y, z = q.unbind(-1)
        ww = w * w
        return torch.stack((
            2 * (ww + x * x) - 1, 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 2 * (ww + y * y) - 1, 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 2 * (ww + z * z) - 1,
        ), -1).unflatten(-1, (3, 3))  # fmt: skip
    t = _tables(q.device, q.dtype)
    products = q.index_select(-1, t.rotmat_left) * q.index_select(-1, t.rotmat_right)
    first, second = products.unflatten(-1, (2, 9)).unbind(-2)
    entries = torch.addcmul(t.rotmat_minus_diagonal, torch.addcmul(first, second, t.rotmat_sign), t.two)
    return entries.unflatten(-1, (3, 3))


def body_z_vertical(q: Tensor) -> Tensor:
    """``[..., 1]``: ``quat_to_rotmat(q)[..., 2, 2:3]``, the vertical component of the body z axis
    (as ``1 - 2 (xx + yy)``), without the other eight entries."""
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


def euler_to_rotmat(angles: Tensor) -> Tensor:
    """``[..., 3, 3]``: the rotation matrix of Z-Y-X Euler angles ``[..., 3]`` (roll, pitch, yaw,
    radians), ``quat_to_rotmat(quat_from_euler(roll, pitch, yaw))`` without the quaternion."""
    if tracing():  # the tables' products, written out
        cr, cp, cy = torch.cos(angles).unbind(-1)
        sr, sp, sy = torch.sin(angles).unbind(-1)
        return torch.stack((
            cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr,
            sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr,
            -sp, cp * sr, cp * cr,
        ), -1).unflatten(-1, (3, 3))  # fmt: skip
    t = _tables(angles.device, angles.dtype)
    factors = torch.cat((torch.cos(angles), torch.sin(angles), t.one.expand(*angles.shape[:-1], 1)), -1)
    products = factors.index_select(-1, t.euler_index).unflatten(-1, (2, 9, 3)).prod(-1)
    return torch.linalg.vecdot(products, t.euler_sign, dim=-2).unflatten(-1, (3, 3))


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
    inv_pi = operands(t.inv_pi, 1.0 / math.pi)
    half_angle = half_dt * omega_body
    theta = norm(half_angle)
    # sin(theta) / theta, 1 at theta = 0 (no division by zero)
    dq = torch.cat((torch.cos(theta), torch.sinc(theta * inv_pi) * half_angle), -1)
    out = quat_mul(q, dq)
    return out / norm(out)


# Small products as broadcast multiply-and-sum (``linalg.vecdot``: one eager op) rather than ``@``:
# as fast for 3x3 and 4x4, fused by torch.compile, and free of BLAS's size-dependent kernel choice,
# so a row's result does not depend on how many rows share its batch (bitwise replay).


def matvec(m: Tensor, v: Tensor) -> Tensor:
    """``m @ v`` over the last two/one dims, batch-size independent."""
    return torch.linalg.vecdot(m, v.unsqueeze(-2))


def vecmat(v: Tensor, m: Tensor) -> Tensor:
    """``v @ m`` (``v`` ``[..., K]``, ``m`` ``[..., K, J]``), batch-size independent."""
    return torch.linalg.vecdot(v.unsqueeze(-1), m, dim=-2)


def transpose_matmul(a: Tensor, b: Tensor) -> Tensor:
    """``a^T @ b`` for batches of small matrices, batch-size independent."""
    return torch.linalg.vecdot(a.unsqueeze(-1), b.unsqueeze(-2), dim=-3)


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


def vee_antisymmetric(m: Tensor) -> Tensor:
    """``1/2 vee(m^T - m)`` (``vee`` the vector of a skew-symmetric matrix):
    ``(m_12 - m_21, m_20 - m_02, m_01 - m_10) / 2``."""
    if tracing():
        return 0.5 * torch.stack((m[..., 1, 2] - m[..., 2, 1], m[..., 2, 0] - m[..., 0, 2], m[..., 0, 1] - m[..., 1, 0]), -1)
    return torch.linalg.vecdot(m.flatten(-2).unsqueeze(-2), _tables(m.device, m.dtype).vee_map)


def heading_to_world(vec: Tensor, yaw: Tensor) -> Tensor:
    """``[N, 3]`` (forward, left, up) in the frame of heading ``yaw`` ``[N, 1]`` (rad from east,
    counter-clockwise) -> world ENU: a rotation about the vertical by ``yaw``."""
    c, s = torch.cos(yaw), torch.sin(yaw)
    fwd, left = vec[..., :1], vec[..., 1:2]
    return torch.cat((c * fwd - s * left, s * fwd + c * left, vec[..., 2:]), -1)
