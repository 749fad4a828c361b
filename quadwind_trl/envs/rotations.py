"""Batched rotation helpers. Quaternions are ``(w, x, y, z)``, unit, rotating body to world."""
from __future__ import annotations

import math

import torch
from torch import Tensor


def quat_mul(a: Tensor, b: Tensor) -> Tensor:
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        -1,
    )


def quat_to_rotmat(q: Tensor) -> Tensor:
    """``[..., 3, 3]`` matrix ``R`` with ``v_world = R @ v_body``; its columns are the body axes."""
    w, x, y, z = q.unbind(-1)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    return torch.stack(
        (
            1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy),
            2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx),
            2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy),
        ),
        -1,
    ).unflatten(-1, (3, 3))


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
    roll = atan2(r[..., 2, 1], r[..., 2, 2])
    pitch = torch.asin(torch.clamp(-r[..., 2, 0], -1.0, 1.0))
    yaw = atan2(r[..., 1, 0], r[..., 0, 0])
    return torch.stack((roll, pitch, yaw), -1)


def quat_integrate(q: Tensor, omega_body: Tensor, half_dt: Tensor | float) -> Tensor:
    """Rotate ``q`` by a constant body rate over ``2 half_dt`` (exact exponential map),
    renormalised. ``half_dt``: half the step, a number or (for an eager caller that steps often:
    no conversion per use) a 0-dim tensor of the rate's dtype."""
    half_angle = half_dt * omega_body
    theta = torch.linalg.vector_norm(half_angle, dim=-1, keepdim=True)
    # sin(theta)/theta, with its Taylor series where theta is tiny (no division by zero)
    sinc = torch.where(theta < 1e-4, 1.0 - theta * theta / 6.0, torch.sin(theta) / theta.clamp_min(1e-12))
    dq = torch.cat((torch.cos(theta), sinc * half_angle), -1)
    out = quat_mul(q, dq)
    return out / torch.linalg.vector_norm(out, dim=-1, keepdim=True)


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


def rotate(r: Tensor, v: Tensor) -> Tensor:
    """``R @ v`` for batches of matrices and vectors."""
    return matvec(r, v)


def rotate_inverse(r: Tensor, v: Tensor) -> Tensor:
    """``R^T @ v``."""
    return vecmat(v, r)


def vee(m: Tensor) -> Tensor:
    """The vector of a skew-symmetric matrix."""
    return torch.stack((m[..., 2, 1], m[..., 0, 2], m[..., 1, 0]), -1)
