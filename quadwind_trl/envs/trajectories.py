"""The horizontal and vertical trajectory libraries, batched by an integer id.

Each pattern is a closed-form planar path ``P(s)`` (by arc length, or by phase for the
lemniscate and the rose) flown with a progress ``s(t)`` that ramps smoothly from hover to
cruise speed. Position, velocity, acceleration and jerk are the exact time derivatives of that
closed form, taken by forward-mode automatic differentiation in float64 when the library is
built, and tabulated at the control instants: the controller only ever reads the reference at
those instants, so a gather replaces nine pattern evaluations per step without approximating
anything.

Timeline of a flight (``t`` from the episode start, ``t_arm`` the arming time):

* horizontal (and ``hover``, a station-keeping reference for tests): on the ground until ``t_arm``; a smooth vertical climb at ``climb_rate_m_s`` to the
  flight's own altitude (per episode); then the pattern, from hover, at that altitude for
  ``horizontal_duration_s``. The climb is analytic at run time because its length depends on the
  altitude; the pattern comes from the table.
* vertical: on the ground until ``t_arm``; the pattern's own climb to ``vertical_top_m`` (the
  table includes it), then a short hover at the top.

The reference heading follows the path tangent (held while the path has no horizontal
tangent), as a survey vehicle with a forward camera flies.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch
from torch import Tensor

from ..config import TrajectoryConfig

HORIZONTAL = ("loiter_circle_h", "racetrack_h", "figure8_h", "cloverleaf_h", "lawnmower_h")
VERTICAL = ("vertical_climb", "spiral_ascent", "figure8_3d", "lawnmower_scan")
# station keeping at a fixed altitude: not in the paper's libraries; for tests and users
HOVER = "hover"
FIXED_ALTITUDE = HORIZONTAL + (HOVER,)
TRAJECTORIES = HORIZONTAL + VERTICAL + (HOVER,)
TRAJECTORY_IDS = {name: i for i, name in enumerate(TRAJECTORIES)}


def smoothstep(x: Tensor) -> Tensor:
    x = x.clamp(0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def ramp_integral(t: Tensor, tau: float) -> Tensor:
    """Integral of ``smoothstep(t / tau)``: 0 before 0, ``t - tau / 2`` after ``tau``."""
    x = (t / tau).clamp(0.0, 1.0)
    inside = tau * x**3 * (1.0 - 0.5 * x)
    return torch.where(t > tau, t - 0.5 * tau, inside)


def _ramp_derivatives(t: Tensor, tau: float) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``ramp_integral`` and its first three time derivatives (the last is zero outside)."""
    x = t / tau
    inside = (x > 0) & (x < 1)
    xc = x.clamp(0.0, 1.0)
    d1 = xc * xc * (3.0 - 2.0 * xc)
    d2 = torch.where(inside, 6.0 * xc * (1.0 - xc) / tau, 0.0)
    d3 = torch.where(inside, (6.0 - 12.0 * xc) / tau**2, 0.0)
    return ramp_integral(t, tau), d1, d2, d3


def climb_profile(t: Tensor, height: Tensor, rate: float, blend: float) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Altitude, climb rate, acceleration and jerk of a smooth climb from 0 to ``height``.

    Constant rate ``rate`` with smoothstep blends of ``blend`` seconds at both ends; reaches
    ``height`` at ``height / rate + blend``. Works on ``[N]`` tensors (batched altitudes).
    """
    duration = height / rate
    up = _ramp_derivatives(t, blend)
    down = _ramp_derivatives(t - duration, blend)
    return tuple(rate * (a - b) for a, b in zip(up, down))  # type: ignore[return-value]


# --- planar paths P(s) -------------------------------------------------------------------------
# Each takes a 0-d float64 tensor and returns [2]; they are differentiated, never hand-derived.


def _circle(radius: float) -> Callable[[Tensor], Tensor]:
    return lambda s: radius * torch.stack((torch.sin(s / radius), -torch.cos(s / radius)))


def _stadium(straight: float, radius: float) -> Callable[[Tensor], Tensor]:
    """Racetrack: two straights joined by 180-degree turns, counter-clockwise, by arc length."""
    half_turn = math.pi * radius
    perimeter = 2 * straight + 2 * half_turn

    def path(s: Tensor) -> Tensor:
        u = torch.remainder(s, perimeter)
        leg1 = torch.stack((-straight / 2 + u, u * 0 - radius))
        a = (u - straight) / radius - math.pi / 2
        turn1 = torch.stack((straight / 2 + radius * torch.cos(a), radius * torch.sin(a)))
        v = u - straight - half_turn
        leg2 = torch.stack((straight / 2 - v, v * 0 + radius))
        b = (u - 2 * straight - half_turn) / radius + math.pi / 2
        turn2 = torch.stack((-straight / 2 + radius * torch.cos(b), radius * torch.sin(b)))
        return torch.where(
            u < straight,
            leg1,
            torch.where(u < straight + half_turn, turn1, torch.where(u < 2 * straight + half_turn, leg2, turn2)),
        )

    return path


def _raster(leg: float, spacing: float, legs: int) -> Callable[[Tensor], Tensor]:
    """Lawnmower: ``legs`` parallel legs along x joined by semicircular turns, by arc length."""
    radius = spacing / 2
    cycle = leg + math.pi * radius
    y0 = -(legs - 1) * spacing / 2

    def path(s: Tensor) -> Tensor:
        i = torch.clamp(torch.floor(s / cycle), 0, legs - 1)
        u = s - i * cycle
        even = torch.remainder(i, 2) == 0
        y_leg = y0 + i * spacing
        straight = torch.stack((torch.where(even, -leg / 2 + u, leg / 2 - u), y_leg))
        phi = (u - leg) / radius
        ang = torch.where(even, -math.pi / 2 + phi, -math.pi / 2 - phi)
        cx = torch.where(even, u * 0 + leg / 2, u * 0 - leg / 2)
        turn = torch.stack((cx + radius * torch.cos(ang), y_leg + radius + radius * torch.sin(ang)))
        return torch.where((u < leg) | (i == legs - 1), straight, turn)

    return path


def _lemniscate(half_length: float) -> Callable[[Tensor], Tensor]:
    """Figure-eight (lemniscate of Gerono), by phase."""
    return lambda s: torch.stack((half_length * torch.sin(s), 0.5 * half_length * torch.sin(2 * s)))


def _rose(radius: float) -> Callable[[Tensor], Tensor]:
    """Four-lobed cloverleaf r = A cos(2 theta), by phase."""
    return lambda s: radius * torch.cos(2 * s) * torch.stack((torch.cos(s), torch.sin(s)))


def _still(s: Tensor) -> Tensor:
    return torch.stack((s * 0, s * 0))


@dataclass(frozen=True)
class _Pattern:
    path: Callable[[Tensor], Tensor]
    by_phase: bool  # progress is a phase (rad) rather than an arc length (m)
    speed: float  # horizontal speed, m/s: constant by arc length, the maximum by phase
    duration: float  # s, from the pattern start
    climb_rate: float = 0.0  # m/s; 0 for the fixed-altitude patterns
    climb_to: float = 0.0  # m


def _patterns(cfg: TrajectoryConfig) -> list[_Pattern]:
    v, vv = cfg.cruise_speed_m_s, cfg.vertical_speed_m_s
    hd = cfg.horizontal_duration_s

    def vertical(path, by_phase, speed, rate):
        duration = cfg.vertical_top_m / rate + cfg.climb_blend_s + cfg.vertical_hold_s
        return _Pattern(path, by_phase, speed, duration, rate, cfg.vertical_top_m)

    r = cfg.vertical_climb_rate_m_s
    return [
        _Pattern(_circle(cfg.loiter_radius_m), False, v, hd),
        _Pattern(_stadium(cfg.racetrack_straight_m, cfg.racetrack_radius_m), False, v, hd),
        _Pattern(_lemniscate(cfg.figure8_half_length_m), True, v, hd),
        _Pattern(_rose(cfg.cloverleaf_radius_m), True, v, hd),
        _Pattern(_raster(cfg.lawnmower_leg_m, cfg.lawnmower_spacing_m, cfg.lawnmower_legs), False, v, hd),
        vertical(_still, False, 0.0, r[0]),
        vertical(_circle(cfg.spiral_radius_m), False, vv, r[1]),
        vertical(_lemniscate(cfg.figure8_3d_half_length_m), True, vv, r[2]),
        vertical(_raster(cfg.scan_leg_m, cfg.scan_spacing_m, cfg.scan_legs), False, vv, r[3]),
        _Pattern(_still, False, 0.0, cfg.hover_duration_s),
    ]


def _progress_rate(pattern: _Pattern) -> float:
    """ds/dt at cruise: the speed for arc-length paths; for phase paths the rate whose fastest
    point is at that speed (a phase-timed lemniscate is 1.46 times faster at its crossing than
    at its ends: timed by its mean speed it would fly well beyond cruise speed there)."""
    if not pattern.by_phase or pattern.speed == 0:
        return pattern.speed
    phases = torch.linspace(0, 2 * math.pi, 4097, dtype=torch.float64)[:-1]
    tangent = torch.vmap(torch.func.jacfwd(pattern.path))(phases)
    return pattern.speed / tangent.norm(dim=-1).max().item()


def _tabulate(pattern: _Pattern, cfg: TrajectoryConfig, dt: float) -> Tensor:
    """``[T, 14]`` float64: pos(3) vel(3) acc(3) jerk(3) yaw yaw_rate at ``t = k dt``."""
    rate = _progress_rate(pattern)
    ramp = cfg.speed_ramp_s

    def position(t: Tensor) -> Tensor:
        s = rate * ramp_integral(t, ramp)
        xy = pattern.path(s)
        if pattern.climb_rate > 0:
            z = climb_profile(t, t.new_tensor(pattern.climb_to), pattern.climb_rate, cfg.climb_blend_s)[0]
        else:
            z = t * 0
        return torch.cat((xy, z.reshape(1)))

    d1 = torch.func.jacfwd(position)
    d2 = torch.func.jacfwd(d1)
    d3 = torch.func.jacfwd(d2)
    steps = int(round(pattern.duration / dt))
    t = torch.arange(steps, dtype=torch.float64) * dt
    chunks = []
    for tc in t.split(40000):
        chunks.append(torch.cat([torch.vmap(f)(tc) for f in (position, d1, d2, d3)], -1))
    kin = torch.cat(chunks)

    # heading along the path tangent (defined even at rest), unwrapped; its rate by the chain rule
    s = rate * ramp_integral(t, ramp)
    tangent = torch.vmap(torch.func.jacfwd(pattern.path))(s)
    curvature_term = torch.vmap(torch.func.jacfwd(torch.func.jacfwd(pattern.path)))(s)
    tx, ty = tangent.unbind(-1)
    cx, cy = curvature_term.unbind(-1)
    norm2 = tx * tx + ty * ty
    has_heading = norm2 > 1e-12
    yaw = torch.where(has_heading, torch.atan2(ty, tx), torch.zeros_like(tx))
    yaw = torch.from_numpy(np.unwrap(yaw.numpy()))
    s_dot = rate * smoothstep(t / ramp)
    yaw_rate = torch.where(has_heading, (tx * cy - ty * cx) / norm2.clamp_min(1e-12) * s_dot, 0.0)
    return torch.cat((kin, yaw[:, None], yaw_rate[:, None]), -1)


@dataclass
class Reference:
    pos: Tensor  # [N, 3] m, world ENU
    vel: Tensor  # [N, 3]
    acc: Tensor  # [N, 3]
    jerk: Tensor  # [N, 3]
    yaw: Tensor  # [N, 1] rad
    yaw_rate: Tensor  # [N, 1] rad/s


class TrajectoryLibrary:
    """All trajectories (the paper's nine and ``hover``), tabulated at the control rate on ``device``.

    ``schedule`` is called once per episode (at reset) and ``reference`` every control step;
    both are batched over sub-envs with different trajectories and altitudes.
    """

    def __init__(
        self, cfg: TrajectoryConfig, control_dt_s: float, device: torch.device | str | None = None, align_steps: int = 10
    ):
        cfg.validate()
        self.cfg = cfg
        self.dt = control_dt_s
        self.align_steps = align_steps  # pattern starts fall on the flight record's grid
        patterns = _patterns(cfg)
        tables = [_tabulate(p, cfg, control_dt_s) for p in patterns]
        longest = max(t.shape[0] for t in tables)
        padded = [torch.cat((t, t[-1:].expand(longest - t.shape[0], -1))) for t in tables]
        # the pattern holds its last sample past its end (never flown: episodes truncate there)
        self.table = torch.stack(padded).to(torch.float32).to(device)  # [9, T, 14]
        self.pattern_steps = torch.tensor([t.shape[0] for t in tables], dtype=torch.int64, device=device)
        # fixed-altitude flights climb to their own altitude first; vertical ones climb in the pattern
        self.fixed_altitude = torch.tensor([name in FIXED_ALTITUDE for name in TRAJECTORIES], device=device)
        self.arm_step = int(round(cfg.arm_time_s / control_dt_s))
        if self.arm_step % align_steps:
            raise ValueError(f"TrajectoryConfig.arm_time_s={cfg.arm_time_s} must fall on the {align_steps}-step log grid")

    @property
    def names(self) -> tuple[str, ...]:
        return TRAJECTORIES

    def schedule(self, traj_id: Tensor, altitude_m: Tensor) -> tuple[Tensor, Tensor]:
        """``(pattern_start_step, end_step)`` per episode: the control step at which the pattern
        table starts (after arming and, for horizontal flights, the climb) and the step at which
        the flight ends."""
        climb_s = torch.where(self.fixed_altitude[traj_id], altitude_m / self.cfg.climb_rate_m_s + self.cfg.climb_blend_s, 0.0)
        start = self.arm_step + torch.ceil(climb_s / self.dt).to(torch.int64)
        start = (start + self.align_steps - 1) // self.align_steps * self.align_steps
        return start, start + self.pattern_steps[traj_id]

    def reference(self, traj_id: Tensor, step: Tensor, pattern_start: Tensor, altitude_m: Tensor) -> Reference:
        """The reference at control step ``step`` (all ``[N]``)."""
        row = (step - pattern_start).clamp(0, self.table.shape[1] - 1)
        entry = self.table[traj_id, row]  # [N, 14]
        t_climb = (step - self.arm_step).to(torch.float32) * self.dt
        height = torch.where(self.fixed_altitude[traj_id], altitude_m, 0.0)
        z, vz, az, jz = climb_profile(t_climb, height, self.cfg.climb_rate_m_s, self.cfg.climb_blend_s)
        climb = torch.stack((z, vz, az, jz), -1)  # [N, 4]
        zero = torch.zeros_like(climb[..., :1])
        kin = entry[..., :12] + torch.cat(
            [torch.cat((zero, zero, climb[..., i : i + 1]), -1) for i in range(4)], -1
        )
        return Reference(
            pos=kin[..., 0:3],
            vel=kin[..., 3:6],
            acc=kin[..., 6:9],
            jerk=kin[..., 9:12],
            yaw=entry[..., 12:13],
            yaw_rate=entry[..., 13:14],
        )
