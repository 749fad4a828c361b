"""The flatness-based PD cascade: the paper's wind-blind baseline, as a pure tensor function.

Outer loop (position, PD with reference-acceleration feedforward)::

    e_p   = clamp(p - p_ref, +-pos_error_limit)
    a_des = -Kp e_p - Kd (v - v_ref) + a_ref + g z_world

The commanded tilt is limited by shrinking the horizontal part of ``a_des`` until its angle from
vertical is at most ``max_tilt`` (the vertical part is kept: altitude has priority). The collective
thrust is ``m a_des . b3`` (the current body z axis), and the desired attitude has ``b3_des`` along
``a_des`` and the reference heading ``yaw_ref`` (Lee, Leok & McClamroch 2010).

Inner loop (attitude, PD on SO(3), gains in N m / rad as the paper's magnitudes imply: scaled by
the inertia, the cascade with these gains would be only marginally stable)::

    e_R = 1/2 vee(R_des^T R - R^T R_des),  e_w = w - R^T R_des w_des
    tau = -K_R e_R - K_w e_w + w x J w

with ``w_des`` from differential flatness: the reference jerk and yaw rate (Mellinger & Kumar
2011). Nothing here knows the wind.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ..config import GRAVITY_M_S2, ControllerConfig, VehicleConfig
from .rotations import matmul, matvec, vee


@dataclass
class ControllerParams:
    kp: Tensor
    kd: Tensor
    k_att: Tensor
    k_rate: Tensor
    pos_error_limit: Tensor
    tan_max_tilt: float
    mass: float
    inertia: Tensor
    thrust_min: float
    thrust_max: float

    @classmethod
    def from_config(
        cls, cfg: ControllerConfig, vehicle: VehicleConfig, device: torch.device | str | None = None
    ) -> "ControllerParams":
        cfg.validate()
        t = lambda v: torch.tensor(v, dtype=torch.float32, device=device)  # noqa: E731
        return cls(
            kp=t(cfg.kp_pos),
            kd=t(cfg.kd_pos),
            k_att=t(cfg.k_att),
            k_rate=t(cfg.k_rate),
            pos_error_limit=t(cfg.pos_error_limit_m),
            tan_max_tilt=math.tan(math.radians(cfg.max_tilt_deg)),
            mass=vehicle.mass_kg,
            inertia=t(vehicle.inertia_kg_m2),
            thrust_min=vehicle.collective_thrust_min_hover * vehicle.hover_thrust_n,
            thrust_max=vehicle.collective_thrust_max_hover * vehicle.hover_thrust_n,
        )


@dataclass
class PDOutput:
    wrench: Tensor  # [N, 4] collective thrust (N) and body torques (N m)
    tilt_cmd: Tensor  # [N, 1] commanded tilt from vertical (rad), after the limit
    tilt_saturated: Tensor  # [N, 1] bool: the tilt limit was active


def pd_control(
    pos: Tensor,
    vel: Tensor,
    rot: Tensor,
    omega: Tensor,
    ref_pos: Tensor,
    ref_vel: Tensor,
    ref_acc: Tensor,
    ref_jerk: Tensor,
    ref_yaw: Tensor,
    ref_yaw_rate: Tensor,
    p: ControllerParams,
) -> PDOutput:
    """The PD wrench for a batch; ``rot`` is the body-to-world rotation matrix ``[N, 3, 3]``,
    ``ref_yaw`` and ``ref_yaw_rate`` are ``[N, 1]``."""
    pos_err = torch.maximum(torch.minimum(pos - ref_pos, p.pos_error_limit), -p.pos_error_limit)
    acc_des = -p.kp * pos_err - p.kd * (vel - ref_vel) + ref_acc
    acc_z = (acc_des[..., 2:] + GRAVITY_M_S2).clamp_min(0.05 * GRAVITY_M_S2)
    horiz = acc_des[..., :2]
    horiz_norm = horiz.norm(dim=-1, keepdim=True)
    horiz_max = acc_z * p.tan_max_tilt
    tilt_saturated = horiz_norm > horiz_max
    horiz = horiz * torch.where(tilt_saturated, horiz_max / horiz_norm.clamp_min(1e-9), 1.0)
    force_des = p.mass * torch.cat((horiz, acc_z), -1)

    b3 = rot[..., :, 2]
    thrust = (force_des * b3).sum(-1, keepdim=True).clamp(p.thrust_min, p.thrust_max)
    force_norm = force_des.norm(dim=-1, keepdim=True)
    b3_des = force_des / force_norm
    heading = torch.cat((torch.cos(ref_yaw), torch.sin(ref_yaw), torch.zeros_like(ref_yaw)), -1)
    b2_des = torch.linalg.cross(b3_des, heading)
    b2_des = b2_des / b2_des.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    b1_des = torch.linalg.cross(b2_des, b3_des)
    rot_des = torch.stack((b1_des, b2_des, b3_des), -1)

    # Angular-velocity feedforward from the reference jerk (flatness), in the desired body frame.
    h_w = (p.mass / force_norm) * (ref_jerk - (ref_jerk * b3_des).sum(-1, keepdim=True) * b3_des)
    omega_des = torch.cat(
        (
            -(h_w * b2_des).sum(-1, keepdim=True),
            (h_w * b1_des).sum(-1, keepdim=True),
            ref_yaw_rate * b3_des[..., 2:],
        ),
        -1,
    )
    rel = matmul(rot.transpose(-1, -2), rot_des)
    err_rot = 0.5 * vee(rel.transpose(-1, -2) - rel)
    err_rate = omega - matvec(rel, omega_des)
    torque = -p.k_att * err_rot - p.k_rate * err_rate + torch.linalg.cross(omega, p.inertia * omega)

    tilt_cmd = torch.acos((b3_des[..., 2:]).clamp(-1.0, 1.0))
    return PDOutput(torch.cat((thrust, torque), -1), tilt_cmd, tilt_saturated)
