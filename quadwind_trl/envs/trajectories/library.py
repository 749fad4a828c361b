"""The trajectory library: every registered pattern tabulated at the control rate, batched by
integer id.

Each pattern (:mod:`.base`) is a closed-form planar path ``P(s)`` (by arc length, or by phase
for the lemniscate and the rose) flown with a progress ``s(t)`` that ramps smoothly from hover
to cruise speed. Position, velocity, acceleration and jerk are the exact time derivatives of
that closed form, taken by forward-mode automatic differentiation in float64 when the library
is built, and tabulated at the control instants: the controller only ever reads the reference
at those instants, so a gather replaces the pattern evaluations per step without approximating
anything.

Timeline of a flight (``t`` from the episode start, ``t_arm`` the arming time):

* level patterns (the horizontal library and ``hover``): on the ground until ``t_arm``; a
  smooth vertical climb at ``climb_rate_m_s`` to the flight's own altitude (per episode); then
  the pattern, from hover, at that altitude for its duration. The climb is analytic at run time
  because its length depends on the altitude; the pattern comes from the table.
* climbing patterns (the vertical library): on the ground until ``t_arm``; the pattern's own
  climb to ``vertical_top_m`` (the table includes it), then a short hover at the top.

The reference heading follows the path tangent (held while the path has no horizontal
tangent), as a survey vehicle with a forward camera flies.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ...config import TrajectoryConfig
from .base import Pattern, fixed_altitude_mask, registered_patterns
from .profiles import climb_profile, ramp_integral, smoothstep


def _progress_rate(pattern: Pattern) -> float:
    """ds/dt at cruise: the speed for arc-length paths; for phase paths the rate whose fastest
    point is at that speed (a phase-timed lemniscate is 1.46 times faster at its crossing than
    at its ends: timed by its mean speed it would fly well beyond cruise speed there)."""
    if not pattern.by_phase or pattern.speed == 0:
        return pattern.speed
    phases = torch.linspace(0, 2 * math.pi, 4097, dtype=torch.float64)[:-1]
    tangent = torch.vmap(torch.func.jacfwd(pattern.path))(phases)
    return pattern.speed / tangent.norm(dim=-1).max().item()


def _with_derivatives(f, order: int):
    """``t -> (f(t), f'(t), ..., f^(order)(t))`` by nested forward-mode differentiation in one
    pass: each level returns its derivative and, as auxiliary output, the lower orders it was
    differentiated through. (Differentiating each order separately repeated every lower one and
    made the library about a third slower to build, per configuration and process; the tables
    are bit-identical.)"""

    def level0(t: Tensor):
        out = f(t)
        return out, (out,)

    def differentiate(inner):
        def level(t: Tensor):
            derivative, lower = torch.func.jacfwd(inner, has_aux=True)(t)
            return derivative, (*lower, derivative)
        return level

    fn = level0
    for _ in range(order):
        fn = differentiate(fn)
    top = fn
    return lambda t: top(t)[1]


def _table_steps(pattern: Pattern, dt: float) -> int:
    """The rows of a pattern's table: its control instants."""
    return int(round(pattern.duration / dt))


def _tabulate(pattern: Pattern, cfg: TrajectoryConfig, dt: float) -> Tensor:
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

    kinematics = _with_derivatives(position, 3)
    steps = _table_steps(pattern, dt)
    t = torch.arange(steps, dtype=torch.float64) * dt
    chunks = []
    for tc in t.split(40000):
        chunks.append(torch.cat(torch.vmap(kinematics)(tc), -1))
    kin = torch.cat(chunks)

    # heading along the path tangent (defined even at rest), unwrapped; its rate by the chain rule
    s = rate * ramp_integral(t, ramp)
    _, tangent, curvature_term = torch.vmap(_with_derivatives(pattern.path, 2))(s)
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
    """Every registered pattern (:mod:`.base`), tabulated at the control rate on ``device``; row
    ``traj_id`` of the tables is the pattern of that id.

    ``schedule`` is called once per episode (at reset) and ``reference`` every control step;
    both are batched over sub-envs with different trajectories and altitudes. A pattern is
    tabulated the first time ``schedule`` meets its id: differentiating a pattern costs a
    fraction of a second to a few seconds of CPU, and an env flies a few of the patterns (its
    regime's, a test's one or two). Every row of the table has its final shape from the start, so
    a compiled step reads rows filled later as it reads the first ones.
    """

    def __init__(
        self, cfg: TrajectoryConfig, control_dt_s: float, device: torch.device | str | None = None, align_steps: int = 10
    ):
        cfg.validate()
        self.cfg = cfg
        self.dt = control_dt_s
        self.align_steps = align_steps  # pattern starts fall on the flight record's grid
        registered = registered_patterns()
        self.names = tuple(registered)
        self._patterns = [pattern(cfg) for pattern in registered.values()]
        steps = [_table_steps(pattern, control_dt_s) for pattern in self._patterns]
        # [num_patterns, T, 14]; NaN until a row is tabulated (a read before that would show)
        self.table = torch.full((len(steps), max(steps), 14), torch.nan, dtype=torch.float32, device=device)
        self._tabulated: set[int] = set()
        self.pattern_steps = torch.tensor(steps, dtype=torch.int64, device=device)
        # fixed-altitude flights climb to their own altitude first; vertical ones climb in the pattern
        self.fixed_altitude = fixed_altitude_mask(device)
        self.arm_step = int(round(cfg.arm_time_s / control_dt_s))
        self._vertical = torch.tensor([False, False, True], device=device)
        self._zero = torch.zeros((), device=device)
        if self.arm_step % align_steps:
            raise ValueError(f"TrajectoryConfig.arm_time_s={cfg.arm_time_s} must fall on the {align_steps}-step log grid")

    def _tabulate_missing(self, traj_id: Tensor) -> None:
        """Tabulate the patterns of ``traj_id`` not tabulated yet (a host read of the ids: at a
        reset, which reads the restarting rows already)."""
        if len(self._tabulated) == len(self._patterns):
            return
        for i in traj_id.unique().tolist():
            if i in self._tabulated:
                continue
            table = _tabulate(self._patterns[i], self.cfg, self.dt)
            # the pattern holds its last sample past its end (never flown: episodes truncate there)
            padded = torch.cat((table, table[-1:].expand(self.table.shape[1] - table.shape[0], -1)))
            self.table[i] = padded.to(torch.float32)
            self._tabulated.add(i)

    def schedule(self, traj_id: Tensor, altitude_m: Tensor) -> tuple[Tensor, Tensor]:
        """``(pattern_start_step, end_step)`` per episode: the control step at which the pattern
        table starts (after arming and, for horizontal flights, the climb) and the step at which
        the flight ends. Tabulates the patterns of ``traj_id`` it has not met before."""
        self._tabulate_missing(traj_id)
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
        # (0, 0, z, 0, 0, vz, ...): each climb term on the vertical of its vector, +0 elsewhere
        kin = entry[..., :12] + torch.where(self._vertical, climb.unsqueeze(-1), self._zero).flatten(-2)
        return Reference(
            pos=kin[..., 0:3],
            vel=kin[..., 3:6],
            acc=kin[..., 6:9],
            jerk=kin[..., 9:12],
            yaw=entry[..., 12:13],
            yaw_rate=entry[..., 13:14],
        )
