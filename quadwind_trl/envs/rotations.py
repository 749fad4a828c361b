"""Batched rotation helpers. Quaternions are ``(w, x, y, z)``, unit, rotating body to world."""
from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor

from .operands import operands


class _Tables(NamedTuple):
    """The constant maps that let :func:`quat_mul` and :func:`quat_to_rotmat` evaluate their
    textbook expressions as one broadcast multiply-and-sum over the products of the
    quaternions' components (a handful of eager ops, not dozens), and the numbers
    :func:`quat_integrate` and :func:`body_z_vertical` combine, as tensors for the eager step
    (:mod:`.operands`)."""

    mul_map: Tensor  # [16, 4]: the Hamilton product's sign of a_i b_j (row 4 i + j) in each component
    rotmat_left: Tensor  # [10]: the components whose products q_l q_r make up R
    rotmat_right: Tensor  # [10]
    rotmat_map: Tensor  # [10, 3, 3]: each product's weight in each entry of R
    euler_index: Tensor  # [2 * 3 * 9]: euler_to_rotmat's factors, of (cos, sin) of the angles and 1
    euler_sign: Tensor  # [2, 9]: the sign of each entry's two products
    vee_map: Tensor  # [9, 3]: vee_antisymmetric's weights of the entries m_ij (row 3 i + j)
    one: Tensor
    inv_pi: Tensor  # quat_integrate: sin(x) / x is torch.sinc(x / pi)


_TABLES: dict[tuple[torch.device, torch.dtype], _Tables] = {}

# (w, x, y, z) = 0 .. 3. The Hamilton product's components, as signed terms a_i b_j
_HAMILTON = (
    ((0, 0, 1), (1, 1, -1), (2, 2, -1), (3, 3, -1)),  # w = aw bw - ax bx - ay by - az bz
    ((0, 1, 1), (1, 0, 1), (2, 3, 1), (3, 2, -1)),  # x = aw bx + ax bw + ay bz - az by
    ((0, 2, 1), (1, 3, -1), (2, 0, 1), (3, 1, 1)),  # y = aw by - ax bz + ay bw + az bx
    ((0, 3, 1), (1, 2, 1), (2, 1, -1), (3, 0, 1)),  # z = aw bz + ax by - ay bx + az bw
)
# R of a unit quaternion in its homogeneous form, row-major: R_00 = ww + xx - yy - zz,
# R_01 = 2 (xy - wz), ...; the products are ww, xx, yy, zz, xy, xz, yz, wx, wy, wz
_ROTMAT_PRODUCTS = ((0, 0), (1, 1), (2, 2), (3, 3), (1, 2), (1, 3), (2, 3), (0, 1), (0, 2), (0, 3))
_ROTMAT = (
    ((1, 1, -1, -1, 0, 0, 0, 0, 0, 0), (0, 0, 0, 0, 2, 0, 0, 0, 0, -2), (0, 0, 0, 0, 0, 2, 0, 0, 2, 0)),
    ((0, 0, 0, 0, 2, 0, 0, 0, 0, 2), (1, -1, 1, -1, 0, 0, 0, 0, 0, 0), (0, 0, 0, 0, 0, 0, 2, -2, 0, 0)),
    ((0, 0, 0, 0, 0, 2, 0, 0, -2, 0), (0, 0, 0, 0, 0, 0, 2, 2, 0, 0), (1, -1, -1, 1, 0, 0, 0, 0, 0, 0)),
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
    """The tables on ``device`` in ``dtype``, made once (the simulator's first ones by its eager
    ``initial``, before any compiled step)."""
    key = (device, dtype)
    if key not in _TABLES:
        mul_map = torch.zeros(16, 4, dtype=dtype)
        for component, terms in enumerate(_HAMILTON):
            for i, j, sign in terms:
                mul_map[4 * i + j, component] = sign
        rotmat_map = torch.tensor(_ROTMAT, dtype=dtype).permute(2, 0, 1)  # [product, row, column]
        left, right = zip(*_ROTMAT_PRODUCTS)
        _TABLES[key] = _Tables(
            mul_map=mul_map.to(device),
            rotmat_left=torch.tensor(left, device=device),
            rotmat_right=torch.tensor(right, device=device),
            rotmat_map=rotmat_map.contiguous().to(device),
            # [product, factor, entry], flattened
            euler_index=torch.tensor([[[_EULER[e][t][0][f] for e in range(9)] for f in range(3)] for t in range(2)],
                                     device=device).flatten(),
            euler_sign=torch.tensor([[_EULER[e][t][1] for e in range(9)] for t in range(2)], dtype=dtype, device=device),
            vee_map=torch.tensor([[0, 0, 0], [0, 0, 0.5], [0, -0.5, 0], [0, 0, -0.5], [0, 0, 0], [0.5, 0, 0],
                                  [0, 0.5, 0], [-0.5, 0, 0], [0, 0, 0]], dtype=dtype, device=device),
            one=torch.tensor(1.0, dtype=dtype, device=device),
            inv_pi=torch.tensor(1.0 / math.pi, dtype=dtype, device=device),
        )
    return _TABLES[key]


def quat_mul(a: Tensor, b: Tensor) -> Tensor:
    """The Hamilton product (``w = aw bw - ax bx - ay by - az bz``, ...): the products
    ``a_i b_j`` weighted by their signs in each component and summed."""
    outer = a.unsqueeze(-1) * b.unsqueeze(-2)
    return torch.linalg.vecdot(outer.reshape(*outer.shape[:-2], 16, 1), _tables(a.device, a.dtype).mul_map, dim=-2)


def quat_to_rotmat(q: Tensor) -> Tensor:
    """``[..., 3, 3]`` matrix ``R`` with ``v_world = R @ v_body`` of a unit quaternion; its
    columns are the body axes."""
    t = _tables(q.device, q.dtype)
    products = q.index_select(-1, t.rotmat_left) * q.index_select(-1, t.rotmat_right)
    return torch.linalg.vecdot(products.reshape(*products.shape[:-1], 10, 1, 1), t.rotmat_map, dim=-3)


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
    t = _tables(angles.device, angles.dtype)
    factors = torch.cat((torch.cos(angles), torch.sin(angles), t.one.expand(*angles.shape[:-1], 1)), -1)
    products = factors.index_select(-1, t.euler_index).unflatten(-1, (2, 3, 9)).prod(-2)
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
    return torch.linalg.vecdot(m.flatten(-2).unsqueeze(-1), _tables(m.device, m.dtype).vee_map, dim=-2)
