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
2011).

The base controller (:class:`BaseController`, the law the residual policy's action is added to)
is this cascade with up to two classical additions to its outer loop, each a config setting of
:class:`~quadwind_trl.config.ControllerConfig` and off by default (the paper's PD, bit for bit):

* **integral action** (``ki_pos``): ``a_des -= Ki I`` with ``I = integral(e_p dt)``, clamped to
  ``+-integral_limit_m_s`` and frozen on the horizontal axes while the tilt limit is active and
  on the vertical one while the thrust limit is, reset at episode start and held before the
  motors arm: the structure of the PX4 multicopter position and velocity controller
  (PX4 Autopilot, ``mc_pos_control``, PositionControl.cpp: conditional integration);
* **disturbance cancellation** (``disturbance``): ``a_des -= F_hat / m`` for an estimated
  external force ``F_hat`` (world frame), either

  - ``"wind_model"``: wind feed-forward, the drag the airframe's own quadratic drag model
    predicts for the air-relative velocity ``v - w_hat`` (``w_hat`` a wind estimate given to the
    step, vertical part zero): with the true model and the true steady wind it cancels the
    wind's force exactly; or
  - ``"observer"``: an acceleration-based disturbance observer in the style of incremental
    nonlinear dynamic inversion (Smeur, Chu & de Croon 2016, J. Guid. Control Dyn. 39(3);
    Tal & Karaman 2021, IEEE T-CST 29(3)): the accelerometer's specific force ``f`` (body) and
    the thrust the rotors are modelled to give (the applied command through the motors'
    first-order lag) give ``F_raw = R (m f - T e3)``, low-pass filtered with time constant
    ``observer_tau_s``; or
  - ``"l1"``: the adaptive estimate of L1 adaptive control (Hovakimyan & Cao 2010, *L1 Adaptive
    Control Theory*, SIAM, ch. 3; as augmenting a geometric quadrotor controller in L1Quad, Wu
    et al. 2025, IEEE T-CST 33(2)): a velocity predictor
    ``v_hat' = (T_hat R e3 + F_l1) / m - g e3 + A_s (v_hat - v)``, ``A_s = -a I``
    (``l1_pole_1_s``), integrated over the control step, and the piecewise-constant adaptation
    law ``F_l1 = -m Phi^-1 exp(A_s dt) (v_hat - v)`` with ``Phi = A_s^-1 (exp(A_s dt) - I)``, i.e.
    ``F_l1 = -m a / (exp(a dt) - 1) (v_hat - v)``; ``F_l1`` is low-pass filtered with
    ``observer_tau_s``, as the observer's force is. It reads the navigation velocity, not the
    accelerometer. Under a constant force ``F`` the law settles at ``exp(-a dt) F`` (95 % at
    ``a = 5 1/s``, ``dt = 10 ms``): the piecewise-constant law's one-sample lag. Unlike L1Quad, which
    cancels only the thrust-axis part in its attitude-level law, the whole force is cancelled in
    the outer loop's desired acceleration, as the observer's is: the cascade turns it into tilt
    and thrust.

A residual policy on the acceleration (``ResidualConfig.acts_on="acceleration"``) reaches the
same place: its correction (``ControlInputs.acc_correction``, world frame) is added to ``a_des``
beside these terms, before the tilt limit.

The law's state (the integral; the observer's or L1's force, its modelled thrust and L1's
predicted velocity) lives in the simulator's state TensorDict (``state["base"]``); nothing here
holds state between calls.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import torch
from torch import Tensor

from typing import Protocol

from tensordict import TensorDict

from ..config import GRAVITY_M_S2, ControllerConfig, VehicleConfig
from .operands import operands
from .rotations import matvec, norm, transpose_matmul, vee_antisymmetric
from .tensordicts import unchecked
from .trajectories.library import Reference
from .vehicle import VehicleParams, drag_force_body


class PDOperands(NamedTuple):
    """The numbers :func:`pd_control` combines with tensors: 0-dim float32 tensors on the gains'
    device for the eager step, Python numbers for a traced one (:mod:`.operands`)."""

    gravity: Tensor | float
    tan_max_tilt: Tensor | float
    mass: Tensor | float
    one: Tensor | float


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
    numbers: PDOperands = field(init=False, repr=False)
    operands: PDOperands = field(init=False, repr=False)

    def __post_init__(self):
        self.numbers = PDOperands(gravity=GRAVITY_M_S2, tan_max_tilt=self.tan_max_tilt, mass=self.mass, one=1.0)
        self.operands = PDOperands(*(torch.tensor(v, dtype=torch.float32, device=self.kp.device) for v in self.numbers))

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
class ClassicalParams:
    """Tensor constants of the outer-loop additions (:class:`ControllerConfig`), for one control step ``dt``."""

    ki: Tensor | None  # [3] 1/s^3; None: no integral action
    integral_limit: Tensor  # [3] m s
    disturbance: str  # ControllerConfig.disturbance
    drag_half_rho_cda: Tensor  # [3] the airframe's drag model, 1/2 rho CdA per body axis
    # 1 - exp(-dt / observer_tau_s), 1 unfiltered: the force filter's step gain (a [N, 1] tensor: one per row, in a search)
    observer_gain: float | Tensor
    motor_gain: float  # 1 - exp(-dt / motor_time_constant_s): the modelled thrust's step gain
    l1_pole: float  # 1/s: a, the predictor's A_s = -a I
    l1_gain: float  # 1/s: a / (exp(a dt) - 1), the adaptation law's Phi^-1 exp(A_s dt)
    mass: float
    dt: float

    @classmethod
    def from_config(cls, cfg: ControllerConfig, vehicle: VehicleConfig, dt_s: float,
                    device: torch.device | str | None = None) -> "ClassicalParams":
        cfg.validate()
        t = lambda v: torch.tensor(v, dtype=torch.float32, device=device)  # noqa: E731
        return cls(
            ki=t(cfg.ki_pos) if cfg.has_integral else None,
            integral_limit=t(cfg.integral_limit_m_s),
            disturbance=cfg.disturbance,
            drag_half_rho_cda=VehicleParams.from_config(vehicle, device).drag_half_rho_cda,  # the simulator's own
            observer_gain=-math.expm1(-dt_s / cfg.observer_tau_s) if cfg.observer_tau_s > 0 else 1.0,
            motor_gain=-math.expm1(-dt_s / vehicle.motor_time_constant_s),
            l1_pole=cfg.l1_pole_1_s,
            l1_gain=cfg.l1_pole_1_s / math.expm1(cfg.l1_pole_1_s * dt_s),
            mass=vehicle.mass_kg,
            dt=dt_s,
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
    acc_extra: Tensor | None = None,
) -> PDOutput:
    """The PD wrench for a batch; ``rot`` is the body-to-world rotation matrix ``[N, 3, 3]``,
    ``ref_yaw`` and ``ref_yaw_rate`` are ``[N, 1]``; ``acc_extra`` ``[N, 3]`` (m/s^2, world) is
    added to the outer loop's desired acceleration before the tilt limit (None: the paper's PD)."""
    k = operands(p.operands, p.numbers)
    pos_err = torch.maximum(torch.minimum(pos - ref_pos, p.pos_error_limit), -p.pos_error_limit)
    acc_des = torch.addcmul(torch.addcmul(ref_acc, p.kp, pos_err, value=-1.0), p.kd, vel - ref_vel, value=-1.0)
    if acc_extra is not None:  # a config constant: the PD alone runs exactly the paper's ops
        acc_des = acc_des + acc_extra
    acc_z = (acc_des[..., 2:] + k.gravity).clamp_min(0.05 * GRAVITY_M_S2)
    horiz = acc_des[..., :2]
    horiz_norm = norm(horiz)
    horiz_max = acc_z * k.tan_max_tilt
    tilt_saturated = horiz_norm > horiz_max
    horiz = horiz * torch.where(tilt_saturated, horiz_max / horiz_norm.clamp_min(1e-9), k.one)
    force_des = k.mass * torch.cat((horiz, acc_z), -1)

    b3 = rot[..., :, 2]
    thrust = (force_des * b3).sum(-1, keepdim=True).clamp(p.thrust_min, p.thrust_max)
    force_norm = norm(force_des)
    b3_des = force_des / force_norm
    heading = torch.cat((torch.cos(ref_yaw), torch.sin(ref_yaw), torch.zeros_like(ref_yaw)), -1)
    b2_des = torch.linalg.cross(b3_des, heading)
    b2_des = b2_des / norm(b2_des).clamp_min(1e-9)
    b1_des = torch.linalg.cross(b2_des, b3_des)
    rot_des = torch.stack((b1_des, b2_des, b3_des), -1)

    # Angular-velocity feedforward from the reference jerk (flatness), in the desired body frame.
    jerk_across = torch.addcmul(ref_jerk, (ref_jerk * b3_des).sum(-1, keepdim=True), b3_des, value=-1.0)
    h_w = jerk_across * (k.mass / force_norm)
    omega_des = torch.cat(
        (
            -(h_w * b2_des).sum(-1, keepdim=True),
            (h_w * b1_des).sum(-1, keepdim=True),
            ref_yaw_rate * b3_des[..., 2:],
        ),
        -1,
    )
    rel = transpose_matmul(rot, rot_des)
    err_rot = vee_antisymmetric(rel)
    err_rate = omega - matvec(rel, omega_des)
    torque = torch.addcmul(torch.addcmul(torch.linalg.cross(omega, p.inertia * omega), p.k_att, err_rot, value=-1.0),
                           p.k_rate, err_rate, value=-1.0)

    tilt_cmd = torch.acos((b3_des[..., 2:]).clamp(-1.0, 1.0))
    return PDOutput(torch.cat((thrust, torque), -1), tilt_cmd, tilt_saturated)


@dataclass
class ControlInputs:
    """What a base controller reads at one control instant (batch ``[N]``; world ENU, body FLU)."""

    pos: Tensor  # [N, 3] m: the navigation solution it flies on
    vel: Tensor  # [N, 3] m/s
    rot: Tensor  # [N, 3, 3] body-to-world, from the measured (or true) attitude
    omega: Tensor  # [N, 3] rad/s, body
    ref: Reference
    specific_force: Tensor  # [N, 3] m/s^2, body: the accelerometer's reading
    thrust_applied: Tensor  # [N, 1] N: the collective thrust commanded over the last control step
    wind_ne: Tensor | None  # [N, 2] m/s (north, east): the wind estimate given to the step, if any
    armed: Tensor  # [N, 1] bool: the motors are armed (the integral and the observer's force advance)
    first: bool  # an episode's first instant: nothing has been applied yet, the state stays as it starts
    # [N, 3] m/s^2, world: the residual policy's correction to the desired acceleration
    # (ResidualConfig.acts_on="acceleration"; None: the residual acts on the wrench, or there is none)
    acc_correction: Tensor | None = None


class BaseController(Protocol):
    """The law the residual policy's action is added to: a pure batched function of its inputs
    and its own state (a TensorDict of batch ``[N]`` kept in the simulator's ``state["base"]``,
    or None for a stateless law)."""

    needs_wind: bool  # it reads ControlInputs.wind_ne (the env then takes keys.BASE_WIND_KEY as an input)
    # it adds ControlInputs.acc_correction to its desired acceleration: a residual on the
    # acceleration can act through it (the simulator refuses that residual on a law without this)
    takes_acc_correction: bool

    def init_state(self, n: int, device: torch.device) -> TensorDict | None:
        """The law's state at an episode's start."""

    def __call__(self, inputs: ControlInputs, state: TensorDict | None) -> tuple[PDOutput, TensorDict | None]:
        """The wrench now and the law's state for the next instant."""


class CascadeController:
    """The paper's PD cascade with the classical additions its config switches on (module
    docstring): the base controller of every env."""

    def __init__(self, pd: ControllerParams, extra: ClassicalParams):
        self.pd, self.extra = pd, extra
        self.needs_wind = extra.disturbance == "wind_model"
        self.takes_acc_correction = True
        self._observer = extra.disturbance == "observer"
        self._l1 = extra.disturbance == "l1"

    def init_state(self, n: int, device: torch.device) -> TensorDict | None:
        state = {}
        if self.extra.ki is not None:
            state["integral"] = torch.zeros(n, 3, device=device)
        if self._observer or self._l1:
            state["force_hat"] = torch.zeros(n, 3, device=device)
            # the hover thrust: an airborne start has been hovering; on the ground the motors are
            # off until arming and the modelled thrust decays to zero long before
            state["thrust_hat"] = torch.full((n, 1), self.pd.mass * GRAVITY_M_S2, device=device)
        if self._l1:  # the predictor starts on the first velocity it reads (the episode's first instant)
            state["vel_hat"] = torch.zeros(n, 3, device=device)
        return TensorDict(state, batch_size=[n]) if state else None

    def __call__(self, inputs: ControlInputs, state: TensorDict | None) -> tuple[PDOutput, TensorDict | None]:
        x, ex = inputs, self.extra
        acc_extra = None
        if ex.ki is not None:
            acc_extra = -ex.ki * state["integral"]
        force = self._external_force(x, state)
        if force is not None:
            cancel = force / ex.mass
            acc_extra = -cancel if acc_extra is None else acc_extra - cancel
        if x.acc_correction is not None:  # the residual on the outer loop, beside the classical terms
            acc_extra = x.acc_correction if acc_extra is None else acc_extra + x.acc_correction
        r = x.ref
        out = pd_control(x.pos, x.vel, x.rot, x.omega, r.pos, r.vel, r.acc, r.jerk, r.yaw, r.yaw_rate, self.pd, acc_extra)
        if state is None:
            return out, state
        if x.first:
            if self._l1:
                state = unchecked(state.batch_size, {**dict(state.items()), "vel_hat": x.vel})
            return out, state
        return out, self._next_state(x, state, out)

    def _external_force(self, x: ControlInputs, state: TensorDict | None) -> Tensor | None:
        """``[N, 3]`` N, world: the force the outer loop cancels (None: none)."""
        if self.needs_wind:
            if x.wind_ne is None:
                raise ValueError("ControllerConfig.disturbance='wind_model' needs a wind estimate: give the env "
                                 "keys.BASE_WIND_KEY (transforms.BaseWindInput does)")
            wind = torch.cat((x.wind_ne[..., 1:2], x.wind_ne[..., 0:1], torch.zeros_like(x.wind_ne[..., :1])), -1)
            air_rel_body = matvec(x.rot.transpose(-1, -2), x.vel - wind)
            return matvec(x.rot, drag_force_body(air_rel_body, self.extra.drag_half_rho_cda))
        if self._observer or self._l1:
            return state["force_hat"]
        return None

    def _next_state(self, x: ControlInputs, state: TensorDict, out: PDOutput) -> TensorDict:
        ex, new = self.extra, {}
        if ex.ki is not None:
            pos_err = torch.maximum(torch.minimum(x.pos - x.ref.pos, self.pd.pos_error_limit), -self.pd.pos_error_limit)
            integral = torch.maximum(torch.minimum(state["integral"] + pos_err * ex.dt, ex.integral_limit), -ex.integral_limit)
            thrust = out.wrench[..., :1]
            thrust_saturated = (thrust <= self.pd.thrust_min) | (thrust >= self.pd.thrust_max)
            # conditional integration: an axis whose actuator limit is active does not wind up
            frozen = torch.cat((out.tilt_saturated, out.tilt_saturated, thrust_saturated), -1)
            new["integral"] = torch.where(frozen | ~x.armed, state["integral"], integral)
        if self._observer or self._l1:
            thrust_hat = state["thrust_hat"] + ex.motor_gain * (x.thrust_applied - state["thrust_hat"])
            if self._observer:
                force = ex.mass * x.specific_force  # the thrust acts along body z alone: subtracted there only
                body = torch.cat((force[..., :2], force[..., 2:] - thrust_hat), -1)
                raw = matvec(x.rot, body)
            else:
                raw, new["vel_hat"] = self._l1_adaptation(x, state, thrust_hat)
            force_hat = state["force_hat"] + ex.observer_gain * (raw - state["force_hat"])
            # on the ground before arming the accelerometer reads the ground's reaction (and a held
            # vehicle's velocity tells nothing): no estimate
            new["force_hat"] = torch.where(x.armed, force_hat, state["force_hat"])
            new["thrust_hat"] = thrust_hat
        return unchecked(state.batch_size, new)

    def _l1_adaptation(self, x: ControlInputs, state: TensorDict, thrust_hat: Tensor) -> tuple[Tensor, Tensor]:
        """L1's unfiltered force now (``[N, 3]`` N, world) and the velocity it predicts for the
        next instant (module docstring), under the thrust modelled now; until the motors arm the
        predictor restarts on the measured velocity."""
        ex = self.extra
        error = state["vel_hat"] - x.vel
        force = -(ex.mass * ex.l1_gain) * error  # the piecewise-constant adaptation law
        thrust_acc = x.rot[..., :, 2] * (thrust_hat / ex.mass)
        acc = thrust_acc + force / ex.mass - ex.l1_pole * error
        acc = torch.cat((acc[..., :2], acc[..., 2:] - GRAVITY_M_S2), -1)
        return force, torch.where(x.armed, state["vel_hat"] + ex.dt * acc, x.vel)


def make_base_controller(cfg: ControllerConfig, vehicle: VehicleConfig, dt_s: float,
                         device: torch.device | str | None = None) -> CascadeController:
    """The base controller a config chooses (:class:`CascadeController` with its additions)."""
    return CascadeController(ControllerParams.from_config(cfg, vehicle, device),
                             ClassicalParams.from_config(cfg, vehicle, dt_s, device))
