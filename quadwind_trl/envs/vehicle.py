"""Rigid-body quadrotor dynamics as pure batched tensor functions.

Frames: world ENU (x east, y north, z up), body FLU (x forward, y left, z up, thrust along +z).

Rotor layout (X configuration), rotor ``i`` at azimuth ``45 + 90 i`` degrees from body x:

====  ============  ==========  =====
 i    position      spin (top)  yaw
====  ============  ==========  =====
 0    front-left    CW          +
 1    rear-left     CCW         -
 2    rear-right    CW          +
 3    front-right   CCW         -
====  ============  ==========  =====

so with ``d = arm / sqrt(2)`` and ``c = k_M / k_T`` the mixing matrix maps rotor thrusts to the
wrench ``(T, tau_x, tau_y, tau_z)``::

    T     =  f0 + f1 + f2 + f3
    tau_x =  d ( f0 + f1 - f2 - f3)
    tau_y =  d (-f0 + f1 + f2 - f3)
    tau_z =  c ( f0 - f1 + f2 - f3)

Integration (one physics step of ``dt``): the first-order motor lag is discretised exactly
(``exp(-dt / tau)``), so a step reaches 63.2 % in ``tau`` whatever ``dt``; translation is
semi-implicit Euler (velocity first, then position), with the position sum compensated
(Kahan): at 600 m a float32 position cannot absorb a step of ``v dt`` below half an ulp
(3e-5 m), which would quantise slow motion to ~0.03 m/s; the carry restores it; rotation uses the midpoint rate for both
Euler's equations and the exponential-map quaternion update, which is second order and keeps
torque-free angular momentum to ~1e-6 per second at 2 ms. Quaternions (renormalised every
step) were chosen over rotation matrices: four numbers, one cheap renormalisation, no drift
in orthogonality to correct.

The air velocity (mean wind plus turbulence) is an input held over the step; drag is quadratic
in the body-frame air-relative velocity, per axis: ``F_i = -1/2 rho CdA_i v_i |v_i|``.

Rotor thrust (``VehicleConfig.rotor_aero``): ``k_T omega^2`` times the ratio
:func:`rotor_thrust_ratio` of blade-element thrust with Glauert's uniform inflow, at the rotor's
climb ratio ``lambda_c = v_z / (omega R)`` (air-relative velocity along the rotor axis, body
``+z``) and advance ratio ``mu = |v_xy| / (omega R)``, to the same in still air. For a
fixed-pitch rotor (Leishman 2006, eqs. 3.56 and 2.117, linear twist ignored)::

    C_T    = (sigma a / 2) (theta / 3 (1 + 3/2 mu^2) - lambda / 2)
    lambda = lambda_c + C_T / (2 sqrt(mu^2 + lambda^2))

solved by Newton's method from the axial-flow solution (exact at ``mu = 0``, where the two
equations are a quadratic): three iterations agree with forty to 1e-9 over the flight envelope
(float64; tests/test_vehicle.py). ``theta`` follows from the hover condition, so the still-air
thrust is exactly ``k_T omega^2``. The hub velocity is the body's (the ``omega x r``
part, under 0.5 m/s at the rates flown, is ignored). Outside momentum theory's range the inputs
are clamped: a descent ratio beyond the hover inflow ratio (7.2 m/s at hover speed; vortex-ring
state) and an advance ratio beyond 0.5 (the blade-element thrust term holds to about there; a
slow rotor in a fast edgewise flow would otherwise gain thrust without bound).

Ground contact: the ground is the plane ``z = 0``. A vehicle on it whose net force does not
lift it rests: zero velocity and body rate, and the accelerometer reads the normal force.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import torch
from torch import Tensor

from ..config import GRAVITY_M_S2, VehicleConfig
from .rotations import quat_integrate, quat_to_rotmat, rotate, rotate_inverse, vecmat


@dataclass
class VehicleParams:
    """Tensor constants derived from :class:`VehicleConfig`, on one device."""

    mass: float
    inertia: Tensor  # [3] diagonal
    mixer: Tensor  # [4, 4] rotor thrusts -> wrench
    mixer_inv: Tensor  # [4, 4]
    thrust_coeff: float
    rotor_thrust_max: float  # N per rotor
    collective_min: float  # N
    collective_max: float  # N
    drag_half_rho_cda: Tensor  # [3] 1/2 rho CdA per body axis
    motor_time_constant: float
    rotor: "RotorAero | None"  # None: static thrust k_T omega^2

    @classmethod
    def from_config(cls, cfg: VehicleConfig, device: torch.device | str | None = None) -> "VehicleParams":
        cfg.validate()
        d = cfg.arm_length_m / math.sqrt(2.0)
        c = cfg.yaw_moment_ratio_m
        mixer = torch.tensor(
            [[1.0, 1.0, 1.0, 1.0], [d, d, -d, -d], [-d, d, d, -d], [c, -c, c, -c]],
            dtype=torch.float64,
        )
        hover = cfg.hover_thrust_n
        return cls(
            mass=cfg.mass_kg,
            inertia=torch.tensor(cfg.inertia_kg_m2, dtype=torch.float32, device=device),
            mixer=mixer.to(torch.float32).to(device),
            mixer_inv=torch.linalg.inv(mixer).to(torch.float32).to(device),
            thrust_coeff=cfg.thrust_coeff,
            rotor_thrust_max=cfg.thrust_coeff * cfg.rotor_speed_max_rad_s**2,
            collective_min=cfg.collective_thrust_min_hover * hover,
            collective_max=cfg.collective_thrust_max_hover * hover,
            drag_half_rho_cda=0.5
            * cfg.air_density_kg_m3
            * torch.tensor([cfg.drag_area_xy_m2, cfg.drag_area_xy_m2, cfg.drag_area_z_m2], device=device),
            motor_time_constant=cfg.motor_time_constant_s,
            rotor=RotorAero.from_config(cfg) if cfg.rotor_aero == "momentum" else None,
        )

    @property
    def collective_limit(self) -> float:
        """N: the most collective thrust a command gets, the allocation's cap or four rotors at
        full speed, whichever is lower."""
        return min(self.collective_max, 4 * self.rotor_thrust_max)


_INFLOW_NEWTON_STEPS = 3
_MAX_PITCH_RAD = 0.5  # ~29 deg effective collective: beyond it a blade section stalls
_MAX_ADVANCE_RATIO = 0.5


@dataclass
class RotorAero:
    """Blade-element constants of one fixed-pitch rotor, derived so hover thrust is ``k_T omega^2``."""

    radius: float  # m
    half_solidity_lift: float  # sigma a / 2
    pitch: float  # rad, effective collective that gives the static thrust coefficient
    hover_inflow: float  # lambda_h = sqrt(C_T0 / 2)
    static_ct: float  # C_T0 = k_T / (rho pi R^4)

    @classmethod
    def from_config(cls, cfg: VehicleConfig) -> "RotorAero":
        ct0 = cfg.thrust_coeff / (cfg.air_density_kg_m3 * math.pi * cfg.rotor_radius_m**4)
        s = 0.5 * cfg.rotor_solidity * cfg.blade_lift_slope_per_rad
        inflow = math.sqrt(ct0 / 2.0)
        pitch = 3.0 * (ct0 / s + inflow / 2.0)
        if pitch > _MAX_PITCH_RAD:
            # each field is within its own range, but together they describe no real rotor
            raise ValueError(
                f"VehicleConfig: rotor_radius_m={cfg.rotor_radius_m}, rotor_solidity={cfg.rotor_solidity} and "
                f"blade_lift_slope_per_rad={cfg.blade_lift_slope_per_rad} need a blade pitch of {math.degrees(pitch):.0f} "
                f"deg to give thrust_coeff={cfg.thrust_coeff} (allowed up to {math.degrees(_MAX_PITCH_RAD):.0f} deg: "
                "the blades would stall); use a larger rotor or more solidity")
        return cls(cfg.rotor_radius_m, s, pitch, inflow, ct0)


class RotorOperands(NamedTuple):
    """The numbers the inflow solve combines, derived from a :class:`RotorAero` in float64 and
    held as 0-dim tensors of the inputs' dtype and device: an eager op converts a Python number
    operand at every use (``aten::_to_copy``), a tensor not at all."""

    radius: Tensor
    descent_limit: Tensor  # -hover_inflow: the clamp of the climb ratio
    blade_ct: Tensor  # s theta / 3: C_T before the advance and inflow terms
    blade_ct_advance: Tensor  # 3/2 s theta / 3: the blade term's growth with mu^2
    neg_inflow_ct: Tensor  # -s / 2: d C_T / d lambda
    inflow_ct: Tensor  # s / 2
    quarter_inflow_ct: Tensor  # s / 8
    half: Tensor
    two: Tensor
    static_ct: Tensor


def rotor_operands(r: RotorAero, device: torch.device | str | None = None,
                   dtype: torch.dtype = torch.float32) -> RotorOperands:
    """``r``'s operands as 0-dim tensors of ``dtype`` on ``device``."""
    s = r.half_solidity_lift
    blade = s * r.pitch / 3.0
    values = (r.radius, -r.hover_inflow, blade, 1.5 * blade, -0.5 * s, 0.5 * s, 0.125 * s, 0.5, 2.0, r.static_ct)
    return RotorOperands(*(torch.tensor(v, dtype=dtype, device=device) for v in values))


def rotor_thrust_ratio(air_rel_body: Tensor, rotor_speed: Tensor, r: RotorAero | RotorOperands) -> Tensor:
    """Thrust ``[N, 4]`` of each rotor relative to its still-air value ``k_T omega^2``, for the
    body-frame velocity relative to the air ``[N, 3]`` and rotor speeds ``[N, 4]`` (rad/s).
    ``r``: the rotor, or its operands (:func:`rotor_operands`) on the inputs' device."""
    o = rotor_operands(r, air_rel_body.device, air_rel_body.dtype) if isinstance(r, RotorAero) else r
    return (rotor_thrust_coefficient(air_rel_body, rotor_speed, o) / o.static_ct).clamp_min(0.0)


def rotor_thrust_coefficient(air_rel_body: Tensor, rotor_speed: Tensor, o: RotorOperands) -> Tensor:
    """``C_T`` ``[N, 4]`` of each rotor (module docstring), negative beyond zero thrust (the
    caller stops there), for the inputs of :func:`rotor_thrust_ratio`."""
    # the ratio multiplies k_T omega^2, so a stopped rotor makes no thrust; the floor keeps it finite
    per_tip_speed = (rotor_speed * o.radius).clamp_min(1.0).reciprocal()
    climb = (air_rel_body[..., 2:] * per_tip_speed).clamp_min(o.descent_limit)
    edgewise = air_rel_body[..., :2].square().sum(-1, keepdim=True)
    mu2 = (edgewise * per_tip_speed.square()).clamp_max(_MAX_ADVANCE_RATIO**2)
    ct_blade = torch.addcmul(o.blade_ct, mu2, o.blade_ct_advance)  # C_T before the inflow term
    # the start: the axial-flow solution, exact at mu = 0, where the two equations are the
    # quadratic 2 lambda^2 + (s/2 - 2 lambda_c) lambda - C_T,blade = 0 (its positive root)
    b = torch.add(o.quarter_inflow_ct, climb, alpha=-0.5)  # the linear coefficient / 4
    inflow = torch.addcmul(ct_blade * o.half, b, b).sqrt() - b
    for _ in range(_INFLOW_NEWTON_STEPS):
        # Newton on f = lambda - lambda_c - C_T / (2 S), S = sqrt(mu^2 + lambda^2), both sides
        # doubled: lambda += (C_T / S - 2 (lambda - lambda_c)) / (2 + (s/2 + C_T lambda / S^2) / S),
        # one fused op per term (addcmul, addcdiv)
        ct = torch.addcmul(ct_blade, inflow, o.neg_inflow_ct)
        per_speed = torch.addcmul(mu2, inflow, inflow).rsqrt()
        ct_per_speed = ct * per_speed
        step_up = torch.add(ct_per_speed, inflow - climb, alpha=-2.0)
        slope = torch.addcmul(o.two, per_speed, torch.addcmul(o.inflow_ct, ct_per_speed * inflow, per_speed))
        inflow = torch.addcdiv(inflow, step_up, slope)
    # beyond zero thrust (inflow faster than the blades' pitch: windmill state) a fixed-pitch
    # propeller brakes rather than pulls; the caller stops at zero thrust
    return torch.addcmul(ct_blade, inflow, o.neg_inflow_ct)


def drag_force_body(air_rel_vel_body: Tensor, half_rho_cda: Tensor) -> Tensor:
    """Quadratic drag per body axis for the body-frame velocity relative to the air."""
    return -half_rho_cda * air_rel_vel_body * air_rel_vel_body.abs()


def allocate(wrench: Tensor, p: VehicleParams) -> Tensor:
    """Rotor-speed commands ``[N, 4]`` (rad/s) for a wrench ``(T, tau_x, tau_y, tau_z)``.

    The collective thrust is clamped to its limits first; rotor thrusts are then clamped to
    what a rotor can produce, which sacrifices torque authority only at saturation.
    """
    thrust = wrench[..., :1].clamp(p.collective_min, p.collective_max)
    wrench = torch.cat((thrust, wrench[..., 1:]), -1)
    rotor_thrust = vecmat(wrench, p.mixer_inv.T).clamp(0.0, p.rotor_thrust_max)
    return torch.sqrt(rotor_thrust / p.thrust_coeff)


class RigidBody(NamedTuple):
    """The vehicle's dynamic state, batched ``[N, ...]``."""

    pos: Tensor  # [N, 3] m, world
    pos_carry: Tensor  # [N, 3] m, the Kahan compensation of ``pos``
    vel: Tensor  # [N, 3] m/s, world
    quat: Tensor  # [N, 4] body to world
    omega: Tensor  # [N, 3] rad/s, body
    rotor: Tensor  # [N, 4] rad/s


class StepConstants(NamedTuple):
    """The numbers one :func:`physics_step` of ``dt`` uses, as 0-dim float32 tensors on the
    simulator's device (``[3]`` for the vectors): an eager op converts a Python number operand at
    every use (``aten::_to_copy``), a tensor not at all."""

    zero: Tensor
    dt: Tensor
    half_dt: Tensor
    motor_decay: Tensor  # exp(-dt / tau): the exact first-order lag over dt
    mass: Tensor
    gravity: Tensor  # [3] (0, 0, g), world
    neg_gravity: Tensor  # [3]
    ground: Tensor  # [3] (-inf, -inf, 0): a position below it is below the ground
    neg_drag: Tensor  # [3] -1/2 rho CdA per body axis
    inertia: Tensor  # [3] diagonal
    rotor_wrench: Tensor  # [4, 6] rotor lifts -> body force (0, 0, T) and torque (module docstring)
    rotor: RotorOperands | None


def step_constants(p: VehicleParams, dt: float, device: torch.device | str | None = None) -> StepConstants:
    """:class:`StepConstants` of a physics step of ``dt`` seconds with vehicle ``p``."""
    num = lambda v: torch.tensor(v, dtype=torch.float32, device=device)  # noqa: E731
    # a rotor's thrust is k_T omega^2 times C_T / C_T0 (momentum) or 1 (static): the factor the
    # per-rotor "lift" (omega^2 C_T or omega^2) is mapped to the wrench with, folded into the mixer
    lift_to_thrust = p.thrust_coeff / (1.0 if p.rotor is None else p.rotor.static_ct)
    mixer = p.mixer.to(torch.float64).cpu()
    wrench = torch.cat((torch.zeros(4, 2, dtype=torch.float64), mixer.T), -1) * lift_to_thrust
    return StepConstants(
        zero=num(0.0), dt=num(dt), half_dt=num(0.5 * dt), motor_decay=num(math.exp(-dt / p.motor_time_constant)),
        mass=num(p.mass), gravity=num([0.0, 0.0, GRAVITY_M_S2]), neg_gravity=num([0.0, 0.0, -GRAVITY_M_S2]),
        ground=num([-math.inf, -math.inf, 0.0]), neg_drag=-p.drag_half_rho_cda.to(torch.float32).to(device),
        inertia=p.inertia.to(torch.float32).to(device), rotor_wrench=wrench.to(torch.float32).to(device),
        rotor=None if p.rotor is None else rotor_operands(p.rotor, device),
    )


def physics_step(
    body: RigidBody, rotor_cmd: Tensor, air_vel_world: Tensor, p: VehicleParams, dt: float,
    k: StepConstants | None = None,
) -> tuple[RigidBody, Tensor]:
    """Advance the rigid body by ``dt``; also returns the specific force (body frame) that an
    ideal accelerometer reads over the step (acceleration minus gravity). ``k``: the step's
    constants (:func:`step_constants` of ``p`` and ``dt`` on the inputs' device), made once by a
    caller that steps often."""
    k = step_constants(p, dt, rotor_cmd.device) if k is None else k
    pos, vel, quat, omega = body.pos, body.vel, body.quat, body.omega
    rotor = torch.lerp(rotor_cmd, body.rotor, k.motor_decay)  # cmd + (rotor - cmd) exp(-dt / tau)
    rot = quat_to_rotmat(quat)
    air_rel_body = rotate_inverse(rot, vel - air_vel_world)
    lift = rotor.square()
    if k.rotor is not None:
        lift = lift * rotor_thrust_coefficient(air_rel_body, rotor, k.rotor).clamp_min(0.0)
    wrench = vecmat(lift, k.rotor_wrench)  # body force (0, 0, T), then the torque
    force_body = torch.addcmul(wrench[..., :3], air_rel_body * k.neg_drag, air_rel_body.abs())  # + drag
    acc = torch.addcdiv(k.neg_gravity, rotate(rot, force_body), k.mass)

    resting = (torch.maximum(pos, acc) <= k.zero)[..., 2:]  # on the ground, not lifting off
    acc = torch.where(resting, k.zero, acc)
    vel = torch.where(resting, k.zero, torch.addcmul(vel, acc, k.dt))
    increment = vel * k.dt - body.pos_carry
    moved = pos + increment
    carry = (moved - pos) - increment
    # below the ground: the height (a Scalar clamp_min keeps -0.0, as this does), its carry and
    # any sink rate to zero; whole-row selects on the vertical component, not slices and concats
    below = moved < k.ground
    pos = torch.where(below, k.zero, moved)
    carry = torch.where(below, k.zero, carry)
    vel = torch.where(below, vel.clamp_min(0.0), vel)

    torque_per_inertia = wrench[..., 3:] / k.inertia
    omega_mid = torch.addcmul(omega, _angular_acceleration(omega, torque_per_inertia, k.inertia), k.half_dt)
    omega_new = torch.addcmul(omega, _angular_acceleration(omega_mid, torque_per_inertia, k.inertia), k.dt)
    quat = quat_integrate(quat, torch.where(resting, k.zero, omega_mid), k.half_dt)
    omega = torch.where(resting, k.zero, omega_new)

    specific_force_body = rotate_inverse(rot, acc + k.gravity)
    return RigidBody(pos, carry, vel, quat, omega, rotor), specific_force_body


def _angular_acceleration(omega: Tensor, torque_per_inertia: Tensor, inertia: Tensor) -> Tensor:
    """Euler's equations, ``I^-1 (tau - omega x I omega)``, for a diagonal ``I``."""
    return torch.addcdiv(torque_per_inertia, torch.linalg.cross(omega, inertia * omega), inertia, value=-1.0)
