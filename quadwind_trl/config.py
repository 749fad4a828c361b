"""Configuration dataclasses for every part of the simulator.

Every physical quantity carries its unit in the field name (``_m``, ``_s``, ``_deg`` ...) or
in its docstring. Values stated by the paper are marked ``paper``; everything else is a choice
of ours, listed with its reasoning in ``docs/simulator.md``. Configs are frozen: build a new
one with :func:`dataclasses.replace` rather than mutating a shared instance.
"""
from __future__ import annotations

import math
import typing
from dataclasses import dataclass, field, fields, is_dataclass, replace
from typing import Literal

GRAVITY_M_S2 = 9.81


def _check_range(owner: str, name: str, value: float, low: float, high: float) -> None:
    if not (low <= value <= high):
        raise ValueError(f"{owner}.{name}={value!r} is outside the allowed range [{low}, {high}]")


@dataclass(frozen=True)
class VehicleConfig:
    """The 2.59 kg survey quadrotor (paper, Section "Vehicle and dynamics").

    Rotor layout: X configuration, rotor ``i`` at azimuth ``45 + 90 i`` degrees from the body
    x axis (0 front-left, 1 rear-left, 2 rear-right, 3 front-right), spinning CW, CCW, CW, CCW
    seen from above. See :mod:`quadwind_trl.envs.vehicle` for the mixing matrix.
    """

    mass_kg: float = 2.59  # paper
    inertia_kg_m2: tuple[float, float, float] = (0.078, 0.082, 0.14)  # paper, diagonal
    arm_length_m: float = 0.25  # paper, hub to rotor axis
    thrust_coeff: float = 1.5e-5  # paper, k_T in N / (rad/s)^2
    yaw_moment_ratio_m: float = 0.055  # paper, k_M / k_T
    motor_time_constant_s: float = 0.05  # paper
    rotor_speed_max_rad_s: float = 1200.0  # paper; the minimum is 0
    collective_thrust_min_hover: float = 0.3  # paper, fraction of hover thrust
    collective_thrust_max_hover: float = 2.5  # paper
    drag_area_xy_m2: float = 0.038  # paper, C_d A along body x and y
    drag_area_z_m2: float = 0.10  # paper, C_d A along body z
    air_density_kg_m3: float = 1.225  # paper
    # How a rotor's thrust at a given speed depends on the air flowing through it (ours: the
    # paper gives only the static k_T). "momentum": blade-element theory with Glauert's uniform
    # inflow (Leishman 2006, Principles of Helicopter Aerodynamics, ch. 2-3, 5): thrust falls
    # when air flows down through the disc faster (climb, a downdraught, a disc tilted into the
    # wind), rises in descent, in an updraught and in edgewise flow (translational lift), and
    # equals k_T omega^2 in still air. "static": k_T omega^2 always
    # (the calibration of the shipped checkpoints; saved configs without the field get it).
    rotor_aero: Literal["momentum", "static"] = "momentum"
    # 10-inch two-blade propellers: the paper's k_T is a static thrust coefficient
    # T / (rho n^2 D^4) = 0.116 at D = 0.254 m, typical of 10 x 4.5-4.7 propellers (UIUC propeller
    # data), and its 1200 rad/s (11,500 rpm) a 10-inch propeller's limit; solidity 2 c / (pi R)
    # for a 2 cm chord at three-quarter radius; 2-D lift slope 5.7 /rad
    rotor_radius_m: float = 0.127
    rotor_solidity: float = 0.10
    blade_lift_slope_per_rad: float = 5.7

    @property
    def hover_thrust_n(self) -> float:
        return self.mass_kg * GRAVITY_M_S2

    @property
    def hover_rotor_speed_rad_s(self) -> float:
        return math.sqrt(self.hover_thrust_n / (4.0 * self.thrust_coeff))

    def validate(self) -> None:
        _check_range("VehicleConfig", "mass_kg", self.mass_kg, 0.05, 50.0)
        _check_range("VehicleConfig", "motor_time_constant_s", self.motor_time_constant_s, 1e-4, 1.0)
        if self.rotor_aero not in ("momentum", "static"):
            raise ValueError(f"VehicleConfig.rotor_aero={self.rotor_aero!r}; allowed: 'momentum', 'static'")
        _check_range("VehicleConfig", "rotor_radius_m", self.rotor_radius_m, 0.01, 2.0)
        _check_range("VehicleConfig", "rotor_solidity", self.rotor_solidity, 0.01, 0.5)
        _check_range("VehicleConfig", "blade_lift_slope_per_rad", self.blade_lift_slope_per_rad, 1.0, 7.0)
        max_total = 4 * self.thrust_coeff * self.rotor_speed_max_rad_s**2
        if self.collective_thrust_max_hover * self.hover_thrust_n > max_total + 1e-9:
            raise ValueError(
                "VehicleConfig.collective_thrust_max_hover exceeds what the rotors can produce "
                f"({max_total / self.hover_thrust_n:.2f} x hover)"
            )


DISTURBANCE_MODELS = ("none", "wind_model", "observer", "l1")  # ControllerConfig.disturbance
OBSERVER_READS = ("accelerometer", "true_specific_force")  # ControllerConfig.observer_reads


@dataclass(frozen=True)
class ControllerConfig:
    """Flatness-based PD cascade (paper): the wind-blind baseline and the residual's base law.

    ``feedback`` picks what the controller reads: ``"truth"`` is the simulator state,
    ``"sensors"`` the raw sample-and-held measurements of :class:`SensorConfig`, ``"estimate"``
    the output of a simple navigation filter over those measurements (:class:`NavigationConfig`),
    as a real autopilot flies. ``docs/simulator.md`` gives the calibration behind the default.
    """

    kp_pos: tuple[float, float, float] = (5.0, 5.0, 7.0)  # paper, 1/s^2
    kd_pos: tuple[float, float, float] = (3.5, 3.5, 4.5)  # paper, 1/s
    k_att: tuple[float, float, float] = (10.0, 10.0, 5.0)  # paper, K_R in N m / rad (not scaled by J)
    k_rate: tuple[float, float, float] = (3.5, 3.5, 2.0)  # paper, K_omega in N m s / rad
    max_tilt_deg: float = 35.0  # paper, commanded-tilt limit
    pos_error_limit_m: tuple[float, float, float] = (12.0, 12.0, 15.0)  # paper
    feedback: Literal["truth", "sensors", "estimate"] = "estimate"
    # The classical additions to the paper's PD (all off by default: the base law is the paper's
    # PD, bit for bit). ``envs/controller.py`` gives the laws, ``regimes.CLASSICAL_CONTROLLERS`` the ones
    # flown beside the RL and docs/simulator.md ("Classical base controllers") how they were tuned.
    # Position-error integral gain (1/s^3); the integral is clamped to +-integral_limit_m_s and
    # frozen on an axis while the tilt or thrust limit is active (conditional integration).
    ki_pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    integral_limit_m_s: tuple[float, float, float] = (3.0, 3.0, 3.0)
    # What the outer loop cancels as an external force: "none"; "wind_model" predicts the
    # airframe's drag from a wind estimate (the env's input ``keys.BASE_WIND_KEY``) and its own
    # velocity; "observer" estimates the force from the accelerometer and the applied thrust;
    # "l1" is L1 adaptive control's estimate, from a velocity predictor's error (no accelerometer).
    # Both estimates are low-pass filtered with time constant observer_tau_s (0: unfiltered).
    disturbance: Literal["none", "wind_model", "observer", "l1"] = "none"
    observer_tau_s: float = 0.3
    # What the observer's force is computed from: "accelerometer", the reading the law flies on;
    # or "true_specific_force", a perfect accelerometer (no noise, bias or sample-and-hold). The
    # second is an idealisation for measuring how much better cancellation could do
    # (studies/observer_bound.py), not a law a vehicle can fly.
    observer_reads: Literal["accelerometer", "true_specific_force"] = "accelerometer"
    # L1's state predictor: the rate (1/s) at which its velocity error decays, A_s = -l1_pole_1_s I
    # (5 1/s: the translational A_s of a public Crazyflie firmware port of L1Quad, Wu et al.,
    # IEEE T-CST 33(2), 2025; with the piecewise-constant adaptation law it matters little)
    l1_pole_1_s: float = 5.0

    @property
    def needs_wind(self) -> bool:
        """The law reads a wind estimate at every step (the env's ``BASE_WIND_KEY`` input)."""
        return self.disturbance == "wind_model"

    @property
    def has_integral(self) -> bool:
        return any(k != 0.0 for k in self.ki_pos)

    def validate(self) -> None:
        _check_range("ControllerConfig", "max_tilt_deg", self.max_tilt_deg, 1.0, 89.0)
        if self.feedback not in ("truth", "sensors", "estimate"):
            raise ValueError(f"ControllerConfig.feedback={self.feedback!r}; allowed: 'truth', 'sensors', 'estimate'")
        for i, (ki, limit) in enumerate(zip(self.ki_pos, self.integral_limit_m_s)):
            _check_range("ControllerConfig", f"ki_pos[{i}]", ki, 0.0, 50.0)
            _check_range("ControllerConfig", f"integral_limit_m_s[{i}]", limit, 0.0, 100.0)
        if self.disturbance not in DISTURBANCE_MODELS:
            raise ValueError(f"ControllerConfig.disturbance={self.disturbance!r}; allowed: {DISTURBANCE_MODELS}")
        _check_range("ControllerConfig", "observer_tau_s", self.observer_tau_s, 0.0, 10.0)
        if self.observer_reads not in OBSERVER_READS:
            raise ValueError(f"ControllerConfig.observer_reads={self.observer_reads!r}; allowed: {OBSERVER_READS}")
        if self.observer_reads != "accelerometer" and self.disturbance != "observer":
            raise ValueError(f"ControllerConfig.observer_reads={self.observer_reads!r} is read by the disturbance observer "
                             f"alone; disturbance={self.disturbance!r} (allowed with it: 'observer')")
        _check_range("ControllerConfig", "l1_pole_1_s", self.l1_pole_1_s, 0.1, 100.0)


def stiffer_inner_loop(cfg: ControllerConfig, scale: float) -> ControllerConfig:
    """``cfg`` with its attitude gain ``K_R`` times ``scale`` and its rate gain ``K_omega`` times
    ``sqrt(scale)``: the same damping ratio, an attitude loop ``sqrt(scale)`` times faster."""
    if scale <= 0:
        raise ValueError(f"stiffer_inner_loop: scale={scale}; allowed: > 0")
    return replace(cfg, k_att=tuple(k * scale for k in cfg.k_att), k_rate=tuple(k * scale ** 0.5 for k in cfg.k_rate))


@dataclass(frozen=True)
class NavigationConfig:
    """Complementary-filter gains (fraction of the innovation applied per new sample); ours.

    Between samples the accelerometer predicts. 0.02 per 10 Hz GPS sample is a 5 s position
    time constant, 0.2 a 0.5 s velocity one; 0.02 per 25 Hz barometer sample a 2 s altitude one.
    They minimise the white-noise part of the navigation error for the paper's noise figures
    (a Monte Carlo of the filter's error dynamics, docs/simulator.md); the ``legacy_walk``
    sensing preset keeps the earlier 0.1 / 0.2 / 0.04 (1 s / 0.5 s / 1 s).

    ``height_reference`` is what anchors the altitude. ``"baro"``: the barometer alone, its
    bias passing through (standalone and SBAS receivers, whose vertical error is metre-level).
    ``"gnss"``: the receiver's height, centimetre-level with RTK, pulls the altitude with
    ``gnss_height_gain``; the barometer still corrects it, less its offset, estimated against
    that reference with ``baro_offset_gain`` (0.005 per 25 Hz sample: the offset error decays
    with a ~28 s time constant, the baro correcting the altitude faster than the GNSS does) -
    what PX4's EKF2 does with ``EKF2_HGT_REF = GPS``, the setting its docs recommend for RTK.
    Configs saved before this field get ``"baro"``.
    """

    gps_position_gain: float = 0.02
    gps_velocity_gain: float = 0.2
    baro_gain: float = 0.02
    height_reference: Literal["baro", "gnss"] = "gnss"
    gnss_height_gain: float = 0.02
    baro_offset_gain: float = 0.005

    def validate(self) -> None:
        for name in ("gps_position_gain", "gps_velocity_gain", "baro_gain", "gnss_height_gain", "baro_offset_gain"):
            _check_range("NavigationConfig", name, getattr(self, name), 0.0, 1.0)
        if self.height_reference not in ("baro", "gnss"):
            raise ValueError(f"NavigationConfig.height_reference={self.height_reference!r}; allowed: 'baro', 'gnss'")


@dataclass(frozen=True)
class MonitorConfig:
    """The runtime monitor: PD alone (residual zero, at once) while the vehicle is near its limits,
    then the residual back through the smoothing and slew limit, from zero (ours; docs/rl.md,
    "Runtime monitor"). It reads what the autopilot knows: the attitude and position the PD flies on.

    Near the limits is any of: the tilt from vertical beyond ``ControllerConfig.max_tilt_deg``
    plus ``tilt_margin_deg`` (the residual's torques are not bound by the PD's tilt limit); the
    total commanded thrust (PD plus residual) at or above ``thrust_fraction`` of the collective the
    rotors give (at the thrust limit more tilt is less lift: the vehicle sinks); the altitude more
    than ``height_below_ref_m`` below the reference (None: not checked). The shipped policy's worst
    episodes reach all three (docs/rl.md, "Where the tail comes from").
    """

    # deg: over 8 standard deviations of the attitude measurement's noise (0.6 deg), and room for
    # the PD's own attitude loop to overshoot its command in gusts (PD alone is beyond 35 deg
    # 2.5-7 % of the time in the worst episodes)
    tilt_margin_deg: float = 5.0
    # the diagnosis's "thrust at limit" (studies/diagnosis.py, THRUST_SATURATED); hover is 0.4
    thrust_fraction: float = 0.98
    # m: above the PD's largest height loss in a typical horizontal-sweep episode (2.2 m on
    # average) and far below the policy's in its worst ones (37-57 m; PD's 17-18 m)
    height_below_ref_m: float | None = 5.0
    # s of PD alone after the last control step near the limits: two time constants of the PD's
    # slower (horizontal) position loop (1 / 1.75 s^-1 = 0.57 s, from kp 5 and kd 3.5), so what the
    # limits left behind has mostly decayed, and ten policy decisions, so the gate cannot chatter
    # at the decision rate
    hold_s: float = 1.0

    def validate(self) -> None:
        _check_range("MonitorConfig", "tilt_margin_deg", self.tilt_margin_deg, 0.0, 45.0)
        # at or below 0.4 (hover thrust over the 2.5 x hover limit) it would trip in hover
        _check_range("MonitorConfig", "thrust_fraction", self.thrust_fraction, 0.5, 1.0)
        if self.height_below_ref_m is not None:
            _check_range("MonitorConfig", "height_below_ref_m", self.height_below_ref_m, 0.5, 100.0)
        _check_range("MonitorConfig", "hold_s", self.hold_s, 0.0, 60.0)


ResidualTarget = Literal["wrench", "acceleration"]
RESIDUAL_TARGETS: tuple[str, ...] = ("wrench", "acceleration")  # ResidualConfig.acts_on


@dataclass(frozen=True)
class ResidualConfig:
    """The RL residual: a correction the policy adds to the base law (paper, Section "Action"),
    scaled, smoothed and slew-limited at every control step.

    ``acts_on`` chooses where it enters. ``"wrench"`` (the paper's): four channels, collective
    thrust (N) and body torques (N m), added to the base law's output. ``"acceleration"``: three
    channels (m/s^2; forward, left and up in the reference heading's frame, the frame of the
    policy's horizontal inputs), rotated into the world frame and added to the cascade's desired
    acceleration beside the integral's and the disturbance observer's terms, before the tilt
    limit: where the classical corrections act, so the policy need not learn the attitude loop
    (docs/rl.md, "The residual on the outer loop").
    """

    acts_on: ResidualTarget = "wrench"
    action_scale: tuple[float, float, float, float] = (10.0, 5.0, 5.0, 5.0)  # paper, N and N m (wrench)
    smoothing: float = 0.7  # paper; weight of the previous applied correction (either target: a 28 ms filter)
    # N, N m per 10 ms step (20 N/s, 2 N m/s): a full-scale wind correction builds up over about a
    # second, while step-to-step exploration noise cannot kick the airframe (K_R is 10 N m/rad)
    slew_limit_per_step: tuple[float, float, float, float] = (0.2, 0.02, 0.02, 0.02)
    # m/s^2 per unit action (acceleration), forward / left / up. Horizontal: the drag acceleration
    # 1/2 rho CdA_xy v^2 / m of the default vehicle (0.038 m^2, 2.59 kg) in the RL regimes'
    # strongest mean wind, 12 m/s, with a two-sigma gust at their strongest intensity, 0.25:
    # v = 12 (1 + 2 x 0.25) = 18 m/s gives 2.9 m/s^2. Up: CdA_z (0.10 m^2) at the fastest climb,
    # 3 m/s, plus two sigma of vertical gust (sigma_w = 0.8 sigma_u, convective, = 2.4 m/s):
    # v = 7.8 m/s gives 1.4 m/s^2. tests/test_residual_acceleration.py recomputes both
    acceleration_scale_m_s2: tuple[float, float, float] = (3.0, 3.0, 1.5)
    # m/s^2 per 10 ms step: a full-scale correction builds up over one second, as the wrench's does
    acceleration_slew_m_s2_per_step: tuple[float, float, float] = (0.03, 0.03, 0.015)
    # None: off, the residual always applies (every result before the monitor, and the default:
    # a policy is reported with and without it); with_monitor switches it on for evaluation
    monitor: MonitorConfig | None = None

    @property
    def channels(self) -> int:
        """The action's width: 4 (thrust, three torques) on the wrench, 3 (forward, left, up) on the acceleration."""
        return len(self.scale)

    @property
    def scale(self) -> tuple[float, ...]:
        """Units per unit action of the target ``acts_on`` chooses (N and N m, or m/s^2)."""
        return self.action_scale if self.acts_on == "wrench" else self.acceleration_scale_m_s2

    @property
    def slew(self) -> tuple[float, ...]:
        """The slew limit per control step of the target ``acts_on`` chooses."""
        return self.slew_limit_per_step if self.acts_on == "wrench" else self.acceleration_slew_m_s2_per_step

    def validate(self) -> None:
        if self.acts_on not in RESIDUAL_TARGETS:
            allowed = ", ".join(map(repr, RESIDUAL_TARGETS))
            raise ValueError(f"ResidualConfig.acts_on={self.acts_on!r}; allowed: {allowed}")
        _check_range("ResidualConfig", "smoothing", self.smoothing, 0.0, 0.999)
        for name in ("slew_limit_per_step", "acceleration_scale_m_s2", "acceleration_slew_m_s2_per_step"):
            value = getattr(self, name)
            if min(value) <= 0:
                raise ValueError(f"ResidualConfig.{name}={value!r}; allowed: every entry > 0")
        if self.monitor is not None:
            if not isinstance(self.monitor, MonitorConfig):
                raise TypeError(f"ResidualConfig.monitor={self.monitor!r}: expected a MonitorConfig or None (off)")
            self.monitor.validate()


@dataclass(frozen=True)
class RewardConfig:
    """Eq. (2) of the paper: r = -a e_xy - b |e_z| - g |u_ff| - d |du_ff| + r_alive, and the crash
    rules (computed by :class:`~quadwind_trl.envs.task.TrackingTask`)."""

    w_xy: float = 1.0  # paper (alpha)
    w_z: float = 1.0  # paper (beta); the regimes' values are presets in quadwind_trl.regimes
    # paper (gamma), on the wrench in N and N m; a correction on the acceleration is weighed as the
    # force it asks of the vehicle (times the mass, in N), so the weights keep their units
    w_ff: float = 0.01
    w_dff: float = 0.02  # paper (delta)
    alive_bonus: float = 0.05  # paper
    crash_penalty: float = -100.0  # paper
    crash_tilt_deg: float = 80.0  # "excessive tilt": beyond this attitude the flight is lost
    takeoff_grace_s: float = 5.0  # ground contact ends an episode only this long after arming


@dataclass(frozen=True)
class TimingConfig:
    """The clocks: physics, control, decisions (env steps) and the flight record."""

    physics_dt_s: float = 0.002  # paper: rigid body at 500 Hz
    control_substeps: int = 5  # paper: PD at 100 Hz
    log_every_control_steps: int = 10  # paper: flight record at 10 Hz
    # control steps one env step (one decision) holds its action for; the PD, smoother and slew
    # limiter still act at every control step. 1: the simulator steps at the control rate (the
    # PD runs, datasets); the RL regimes' preset (quadwind_trl.regimes.RL_PRESETS) is 10, one
    # decision per 10 Hz log tick (docs/rl.md: why). Must divide log_every_control_steps.
    hold_control_steps: int = 1

    @property
    def control_dt_s(self) -> float:
        return self.physics_dt_s * self.control_substeps

    @property
    def log_dt_s(self) -> float:
        return self.control_dt_s * self.log_every_control_steps

    @property
    def decisions_per_log(self) -> int:
        """Env steps per 10 Hz log tick."""
        return self.log_every_control_steps // self.hold_control_steps

    def validate(self) -> None:
        _check_range("TimingConfig", "hold_control_steps", self.hold_control_steps, 1, self.log_every_control_steps)
        if self.log_every_control_steps % self.hold_control_steps:
            # an env step must end on every 10 Hz tick, or the feature history skips samples
            raise ValueError(f"TimingConfig.hold_control_steps={self.hold_control_steps} must divide "
                             f"TimingConfig.log_every_control_steps={self.log_every_control_steps}")


@dataclass(frozen=True)
class WindProfileConfig:
    """Turbulence-free mean wind: power law in altitude plus linear veer (paper Eq. 1)."""

    reference_height_m: float = 10.0  # paper, z_ref
    max_horizontal_wind_m_s: float = 20.0  # paper, the cap on the horizontal wind magnitude
    # what the cap clips: "mean" (the power-law profile, as the paper defines the cap) or
    # "total" (mean plus gusts, truncating the gust distribution's upper tail)
    cap_applies_to: Literal["mean", "total"] = "mean"

    def validate(self) -> None:
        if self.cap_applies_to not in ("mean", "total"):
            raise ValueError(f"WindProfileConfig.cap_applies_to={self.cap_applies_to!r}; allowed: 'mean', 'total'")


TURBULENCE_LAYOUTS = ("full", "paper_grid")  # TurbulenceConfig.layout


@dataclass(frozen=True)
class TurbulenceConfig:
    """Spectral-mode von Karman turbulence (TurboGenPY-style); docs/atmosphere.md section 2.

    ``layout="full"`` (default): ``num_modes`` log-spaced dimensionless wavenumbers
    ``kappa = k L`` over ``kappa_range``, amplitudes normalised to the requested variance,
    evaluated at the vehicle (no grid).
    ``layout="paper_grid"``: the paper's stated field: ``cube_points``^3 cubes over
    ``cube_size_m`` synthesised TurboGenPY's way on the grid (k linear from ``2 pi / cube_size_m``
    to the grid's Nyquist, no renormalisation), interpolated trilinearly with periodic
    wrap-around. A bank of ``cube_bank_size`` realisations per length scale of
    ``cube_length_scales_m`` (m) is shared by all episodes (3 MB each); an episode uses the
    nearest length scale, a realisation picked by its seed, its own rotation and offset.
    Both layouts get the same stability anisotropy, chosen by ``anisotropy``: ``"stretch"``
    (default) is exactly divergence-free (docs/atmosphere.md 2.3); ``"local_scaling"`` scales the
    isotropic field's components in the local mean-wind frame, which breaks divergence-freeness
    (|div|/|grad| 0.05-0.13). It is the field every config saved before the stretch flew (the shipped
    estimators and policies, their committed results), kept so those re-fly bit for bit;
    :func:`config_from_dict` gives it to a saved config that names no anisotropy.
    """

    enabled: bool = True
    num_modes: int = 300  # paper
    layout: Literal["full", "paper_grid"] = "full"
    anisotropy: Literal["stretch", "local_scaling"] = "stretch"
    kappa_range: tuple[float, float] = (2 * math.pi / 60.0, 800.0)  # dimensionless k L
    cube_size_m: float = 1200.0  # paper
    cube_points: int = 64  # paper
    cube_length_scales_m: tuple[float, ...] = (60.0, 90.0, 135.0, 200.0, 300.0)  # spans the designs' 60-300 m
    cube_bank_size: int = 2  # realisations per length scale
    skeleton_seed: int = 20240611
    intensity_altitude_exponent: float = 0.05  # sigma_u = I U(z) (z/z_ref)^(-this): mild decay
    # sigma_v / sigma_u and sigma_w / sigma_u for the neutral, stable and convective regimes
    # (after Panofsky & Dutton 1984 and Stull 1988; see docs/atmosphere.md)
    stability_ratios: tuple[tuple[float, float], ...] = ((0.80, 0.52), (0.75, 0.45), (0.95, 0.80))

    def validate(self) -> None:
        if self.layout not in TURBULENCE_LAYOUTS:
            raise ValueError(f"TurbulenceConfig.layout={self.layout!r}; allowed: {', '.join(map(repr, TURBULENCE_LAYOUTS))}")
        if self.anisotropy not in ("stretch", "local_scaling"):
            raise ValueError(f"TurbulenceConfig.anisotropy={self.anisotropy!r}; allowed: 'stretch', 'local_scaling'")
        _check_range("TurbulenceConfig", "num_modes", self.num_modes, 1, 100_000)
        if not 0 < self.kappa_range[0] < self.kappa_range[1]:
            raise ValueError(f"TurbulenceConfig.kappa_range={self.kappa_range!r} must be increasing and positive")
        _check_range("TurbulenceConfig", "cube_points", self.cube_points, 2, 512)
        _check_range("TurbulenceConfig", "cube_bank_size", self.cube_bank_size, 1, 1000)
        if self.cube_size_m <= 0 or not self.cube_length_scales_m or min(self.cube_length_scales_m) <= 0:
            raise ValueError(
                f"TurbulenceConfig.cube_size_m={self.cube_size_m}, cube_length_scales_m={self.cube_length_scales_m}: "
                "allowed a positive size and a non-empty tuple of positive length scales (m)"
            )
        if len(self.stability_ratios) != 3 or any(not (r > 0) for pair in self.stability_ratios for r in pair):
            raise ValueError(
                f"TurbulenceConfig.stability_ratios={self.stability_ratios!r}: allowed three (sigma_v/sigma_u, "
                "sigma_w/sigma_u) pairs (neutral, stable, convective), every ratio > 0 (the stretch divides by them)"
            )


@dataclass(frozen=True)
class SensorChannelConfig:
    """One instrument, per axis: sample rate, white noise, and a first-order Gauss-Markov bias.

    The bias obeys ``db = -b / tau dt + q dW`` with ``tau = bias_corr_time_s`` and
    ``q = bias_drive_std_per_sqrt_s``: stationary standard deviation ``q sqrt(tau / 2)``
    (:attr:`bias_std`), drawn at the episode start. ``tau = inf`` is the unbounded limit, a random
    walk that starts at zero (the ``legacy_walk`` preset). Build bounded channels with
    :meth:`gauss_markov`, which takes the datasheet-style (std, correlation time) pair.
    """

    rate_hz: float
    noise_std: float
    bias_drive_std_per_sqrt_s: float = 0.0
    bias_corr_time_s: float = math.inf

    @classmethod
    def gauss_markov(cls, rate_hz: float, noise_std: float, bias_std: float, corr_time_s: float) -> "SensorChannelConfig":
        return cls(rate_hz, noise_std, bias_std * math.sqrt(2.0 / corr_time_s), corr_time_s)

    @property
    def bias_std(self) -> float:
        """Stationary standard deviation of the bias (0 for a walk: it starts at zero)."""
        if math.isinf(self.bias_corr_time_s):
            return 0.0
        return self.bias_drive_std_per_sqrt_s * math.sqrt(self.bias_corr_time_s / 2.0)

    def validate(self, name: str) -> None:
        _check_range(f"SensorConfig.{name}", "rate_hz", self.rate_hz, 0.01, 10_000.0)
        _check_range(f"SensorConfig.{name}", "noise_std", self.noise_std, 0.0, 1e6)
        _check_range(f"SensorConfig.{name}", "bias_drive_std_per_sqrt_s", self.bias_drive_std_per_sqrt_s, 0.0, 1e6)
        _check_range(f"SensorConfig.{name}", "bias_corr_time_s", self.bias_corr_time_s, 1e-3, math.inf)


_gm = SensorChannelConfig.gauss_markov
_DEG = math.radians
# u-blox ZED-F9P datasheet (UBX-17051259): horizontal accuracy RTK 0.01 m + 1 ppm CEP, SBAS
# 1.0 m CEP, standalone (PVT) 1.5 m CEP; velocity 0.05 m/s. CEP = 1.1774 sigma for a circular
# normal error, so sigma per axis = CEP / 1.1774. Correlation times after Groves (2013, Sec.
# 9.4 and 7.4): residual ionosphere/ephemeris errors (standalone, SBAS) vary over tens of
# minutes; what remains under RTK is multipath, correlated over about a minute.
_GNSS = {
    "rtk": (_gm(10.0, 0.7, 0.011 / 1.1774, 60.0), _gm(10.0, 0.15, 0.005, 60.0)),
    "sbas": (_gm(10.0, 0.7, 1.0 / 1.1774, 600.0), _gm(10.0, 0.15, 0.02, 600.0)),
    "standalone": (_gm(10.0, 0.7, 1.5 / 1.1774, 600.0), _gm(10.0, 0.15, 0.02, 600.0)),
}


@dataclass(frozen=True)
class SensorConfig:
    """The small-UAS sensor suite (paper, Section "Sensors"); noise in SI units (m, m/s, rad...).

    White noise and rates are the paper's. The biases are ours (the paper says only "slowly
    drifting"): bounded Gauss-Markov processes from datasheets, the receiver class chosen by
    the sensing preset (``SENSOR_PRESETS``; default ``rtk``). docs/simulator.md lists sources.
    """

    enabled: bool = True
    gps_pos: SensorChannelConfig = _GNSS["rtk"][0]  # m
    gps_vel: SensorChannelConfig = _GNSS["rtk"][1]  # m/s
    # BMP388: relative accuracy +-0.08 hPa (+-0.66 m) over its range, offset temperature
    # coefficient +-0.75 Pa/K (6 cm/K); a few kelvin over a flight and the synoptic pressure
    # tendency (~1 hPa / 3 h) give a slowly varying 0.15 m
    baro_alt: SensorChannelConfig = _gm(25.0, 0.8, 0.15, 300.0)  # m
    # an AHRS levels with the accelerometer: its 0.005 m/s^2 bias tilts it by ~0.03 deg; 0.1
    # deg allows for misalignment. Yaw from a magnetometer: 0.5 deg of slowly varying disturbance
    attitude_rp: SensorChannelConfig = _gm(50.0, _DEG(0.6), _DEG(0.1), 300.0)  # rad
    attitude_yaw: SensorChannelConfig = _gm(50.0, _DEG(1.5), _DEG(0.5), 300.0)  # rad
    # ICM-42688-P / BMI088 class: gyro bias instability ~3 deg/h, in-run drift with temperature
    # ~0.005 deg/s/K; accelerometer offset drift ~0.15 mg/K: a few kelvin in flight
    gyro: SensorChannelConfig = _gm(200.0, _DEG(0.3), _DEG(0.02), 300.0)  # rad/s
    accel: SensorChannelConfig = _gm(200.0, 0.05, 0.005, 300.0)  # m/s^2

    def channels(self) -> dict[str, SensorChannelConfig]:
        return {f.name: getattr(self, f.name) for f in fields(self) if isinstance(getattr(self, f.name), SensorChannelConfig)}

    def validate(self) -> None:
        for name, ch in self.channels().items():
            ch.validate(name)
        if self.gyro.rate_hz != self.accel.rate_hz:
            raise ValueError(f"SensorConfig: gyro.rate_hz={self.gyro.rate_hz} and accel.rate_hz={self.accel.rate_hz} "
                             "must be equal (one IMU)")


_walk = SensorChannelConfig
# The calibration before bounded biases (kept so the shipped estimators and policies, and the
# results they made, stay reproducible): unbounded walks from zero, and the gyro and
# accelerometer sampled at the 100 Hz control instants (labelled 200 Hz then, sampled at 100).
LEGACY_SENSORS = SensorConfig(
    gps_pos=_walk(10.0, 0.7, 0.03),
    gps_vel=_walk(10.0, 0.15, 0.005),
    baro_alt=_walk(25.0, 0.8, 0.02),
    attitude_rp=_walk(50.0, _DEG(0.6), _DEG(0.01)),
    attitude_yaw=_walk(50.0, _DEG(1.5), _DEG(0.02)),
    gyro=_walk(100.0, _DEG(0.3), _DEG(0.005)),
    accel=_walk(100.0, 0.05, 0.001),
)
LEGACY_NAVIGATION = NavigationConfig(gps_position_gain=0.1, gps_velocity_gain=0.2, baro_gain=0.04, height_reference="baro")

SensorPreset = Literal["rtk", "sbas", "standalone", "legacy_walk"]
# name -> (sensors, navigation filter). The receiver classes differ in the GNSS biases and so in
# the height reference: only an RTK receiver's height beats the barometer's.
SENSOR_PRESETS: dict[str, tuple[SensorConfig, NavigationConfig]] = {
    **{name: (replace(SensorConfig(), gps_pos=pos, gps_vel=vel),
              NavigationConfig(height_reference="gnss" if name == "rtk" else "baro")) for name, (pos, vel) in _GNSS.items()},
    "legacy_walk": (LEGACY_SENSORS, LEGACY_NAVIGATION),
}


@dataclass(frozen=True)
class TrajectoryConfig:
    """Sizes, speeds and durations of the two trajectory libraries (ours: the paper is silent).

    Horizontal flights: on the ground until ``arm_time_s``, climb at ``climb_rate_m_s`` to the
    flight altitude, then fly the pattern for ``horizontal_duration_s`` at ``cruise_speed_m_s``.
    Vertical flights arm at ``arm_time_s`` and climb to ``vertical_top_m`` while flying their
    pattern.
    """

    arm_time_s: float = 1.0  # paper (vertical regime)
    climb_rate_m_s: float = 3.0
    climb_blend_s: float = 3.0  # smooth start and stop of the climb
    speed_ramp_s: float = 5.0  # patterns start from hover and reach cruise speed over this
    cruise_speed_m_s: float = 10.0
    horizontal_duration_s: float = 180.0
    loiter_radius_m: float = 60.0
    racetrack_straight_m: float = 240.0
    racetrack_radius_m: float = 50.0
    figure8_half_length_m: float = 100.0
    cloverleaf_radius_m: float = 100.0
    lawnmower_leg_m: float = 240.0
    lawnmower_spacing_m: float = 60.0
    lawnmower_legs: int = 8
    vertical_top_m: float = 600.0  # paper
    # horizontal speed of the vertical patterns: the survey cruise speed, as the horizontal
    # patterns fly (was 6 m/s: then the drag and turn error a controller can act on was too small
    # beside the navigation error to leave the paper's headroom; docs/simulator.md, experiment V2)
    vertical_speed_m_s: float = 10.0
    vertical_climb_rate_m_s: tuple[float, float, float, float] = (3.0, 2.5, 2.5, 2.0)
    vertical_hold_s: float = 5.0  # hover at the top before the flight ends
    spiral_radius_m: float = 50.0
    figure8_3d_half_length_m: float = 80.0
    scan_leg_m: float = 200.0
    scan_spacing_m: float = 40.0
    scan_legs: int = 10
    hover_duration_s: float = 60.0

    def validate(self) -> None:
        _check_range("TrajectoryConfig", "cruise_speed_m_s", self.cruise_speed_m_s, 0.5, 25.0)
        _check_range("TrajectoryConfig", "climb_rate_m_s", self.climb_rate_m_s, 0.2, 15.0)
        _check_range("TrajectoryConfig", "vertical_top_m", self.vertical_top_m, 10.0, 3000.0)


@dataclass(frozen=True)
class EnvConfig:
    """Everything :class:`~quadwind_trl.envs.QuadWindEnv` needs; presets below."""

    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    controller: ControllerConfig = field(default_factory=ControllerConfig)
    navigation: NavigationConfig = field(default_factory=NavigationConfig)
    residual: ResidualConfig = field(default_factory=ResidualConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    timing: TimingConfig = field(default_factory=TimingConfig)
    wind: WindProfileConfig = field(default_factory=WindProfileConfig)
    turbulence: TurbulenceConfig = field(default_factory=TurbulenceConfig)
    sensors: SensorConfig = field(default_factory=SensorConfig)
    trajectories: TrajectoryConfig = field(default_factory=TrajectoryConfig)

    def validate(self) -> "EnvConfig":
        from .validation import validate_config  # the generic checks; imported here so that the configs need no torch

        validate_config(self)
        for f in fields(self):
            sub = getattr(self, f.name)
            if hasattr(sub, "validate"):
                sub.validate()
        return self


Sensing = Literal["navigation", "no_bias", "true_state"]
SENSING: tuple[Sensing, ...] = ("navigation", "no_bias", "true_state")


def with_sensor_preset(cfg: EnvConfig, preset: SensorPreset) -> EnvConfig:
    """``cfg`` with the sensors and navigation filter of a named preset (``SENSOR_PRESETS``)."""
    if preset not in SENSOR_PRESETS:
        raise ValueError(f"sensor preset {preset!r}; allowed: {tuple(SENSOR_PRESETS)}")
    sensors, navigation = SENSOR_PRESETS[preset]
    return replace(cfg, sensors=replace(sensors, enabled=cfg.sensors.enabled), navigation=navigation)


def with_sensing(cfg: EnvConfig, sensing: Sensing) -> EnvConfig:
    """``cfg`` with the PD's sensing idealised: ``"navigation"`` leaves it as it is (the nav
    filter over noisy, biased sensors); ``"no_bias"`` switches every sensor's bias off (zero
    drive, so also a zero start) and keeps the white noise; ``"true_state"`` makes the PD read
    the simulator state (the sensors, and so the estimator and the policy's sensor channels,
    are unchanged). The error budget (``studies/error_budget.py``) and the PPO recipes'
    ``--sensing`` use it."""
    if sensing == "navigation":
        return cfg
    if sensing == "no_bias":
        unbiased = {name: replace(ch, bias_drive_std_per_sqrt_s=0.0) for name, ch in cfg.sensors.channels().items()}
        return replace(cfg, sensors=replace(cfg.sensors, **unbiased))
    if sensing == "true_state":
        return replace(cfg, controller=replace(cfg.controller, feedback="truth"))
    raise ValueError(f"sensing={sensing!r}; allowed: {SENSING}")


def with_monitor(cfg: EnvConfig, monitor: MonitorConfig | None = MonitorConfig()) -> EnvConfig:
    """``cfg`` with the runtime monitor switched on (``monitor``; None switches it off): a config
    override for flying a trained policy with it (``evaluation.ablation.fly_controllers``)."""
    return replace(cfg, residual=replace(cfg.residual, monitor=monitor))


def config_to_dict(cfg) -> dict:
    """A JSON-ready nested dict of a (nested) config dataclass, for manifests."""
    if is_dataclass(cfg):
        return {f.name: config_to_dict(getattr(cfg, f.name)) for f in fields(cfg)}
    if isinstance(cfg, (tuple, list)):
        return [config_to_dict(v) for v in cfg]
    return cfg


def config_differences(a, b) -> list[str]:
    """The top-level fields (e.g. ``vehicle``, ``reward``) in which two configs of one dataclass differ."""
    return [f.name for f in fields(a) if getattr(a, f.name) != getattr(b, f.name)]


def config_from_dict(cls, data: dict):
    """Rebuild a (nested) config dataclass from :func:`config_to_dict` output (JSON lists become
    tuples again; unknown keys fail loudly)."""
    if cls is SensorConfig and _is_walk_schema(data):
        return _legacy_sensors(data)
    if cls is TurbulenceConfig and "anisotropy" not in data:
        data = dict(data, anisotropy="local_scaling")  # saved before the divergence-free stretch
    if cls is VehicleConfig and "rotor_aero" not in data:
        data = dict(data, rotor_aero="static")  # saved before the inflow-dependent rotor thrust
    if cls is NavigationConfig and "height_reference" not in data:
        data = dict(data, height_reference="baro")  # saved before the GNSS height reference
    if cls is EnvConfig and "hold_control_steps" in data.get("residual", {}):
        # saved when the hold was a residual setting (the shipped policies): it is a timing one
        residual = dict(data["residual"])
        data = dict(data, residual=residual, timing=dict(data.get("timing", {}),
                                                          hold_control_steps=residual.pop("hold_control_steps")))
    hints = typing.get_type_hints(cls)
    names = [f.name for f in fields(cls)]
    unknown = set(data) - set(names)
    if unknown:
        raise KeyError(f"{cls.__name__} has no fields {sorted(unknown)}; allowed: {names}")
    kwargs = {}
    for f in fields(cls):
        if f.name not in data:
            continue
        value, hint = data[f.name], hints[f.name]
        if value is not None and type(None) in typing.get_args(hint):  # an optional sub-config that is set
            hint = next(h for h in typing.get_args(hint) if h is not type(None))
        if is_dataclass(hint):
            value = config_from_dict(hint, value)
        elif isinstance(value, list):
            value = _as_tuple(value)
        kwargs[f.name] = value
    return cls(**kwargs)


def _as_tuple(value):
    return tuple(_as_tuple(v) for v in value) if isinstance(value, list) else value


def _is_walk_schema(data: dict) -> bool:
    return any(isinstance(v, dict) and "bias_walk_std_per_sqrt_s" in v for v in data.values())


def _legacy_sensors(data: dict) -> SensorConfig:
    """Configs saved before the Gauss-Markov biases (the shipped checkpoints) are the
    ``legacy_walk`` preset; refuse any that differs from it in noise or walk."""
    legacy = LEGACY_SENSORS.channels()
    for name, ch in legacy.items():
        saved = data[name]
        if (saved["noise_std"], saved["bias_walk_std_per_sqrt_s"]) != (ch.noise_std, ch.bias_drive_std_per_sqrt_s):
            raise ValueError(f"saved SensorConfig.{name}={saved} is not the legacy_walk calibration (noise_std="
                             f"{ch.noise_std}, bias_walk_std_per_sqrt_s={ch.bias_drive_std_per_sqrt_s}); cannot map it")
    return replace(LEGACY_SENSORS, enabled=data.get("enabled", True))
