"""The task the vehicle is asked to do: reward and episode end, in one place.

:class:`QuadWindEnv` flies the physics (:class:`~quadwind_trl.envs.simulator.QuadSimulator`) and
asks its task, after every 10 ms control step, for the shaped reward and whether the episode has
ended; once per decision (``TimingConfig.hold_control_steps`` control steps) it adds the crash
penalty. Replace the task to change what is rewarded or what ends an episode:
``QuadWindEnv(config, task=MyTask(config))`` with any object that has the three methods of
:class:`Task` (subclassing :class:`TrackingTask` is the short way). Tasks read the simulator's
``params`` / ``state`` TensorDicts (keys in :mod:`quadwind_trl.envs.simulator`) and must stay
pure and branch-free (no host synchronisation: they run inside the held step and under
``torch.compile``).
"""
from __future__ import annotations

import math
from typing import NamedTuple, Protocol

import torch
from tensordict import TensorDict
from torch import Tensor

from ..config import EnvConfig
from .operands import operands
from .rotations import body_z_vertical, norm
from .tensordicts import entry


class Task(Protocol):
    def step_reward(self, params: TensorDict, before: TensorDict, after: TensorDict) -> Tensor:
        """``[N, 1]`` reward of the control step from state ``before`` to state ``after``."""

    def done(self, params: TensorDict, state: TensorDict) -> tuple[Tensor, Tensor]:
        """``(terminated, truncated)``, bool ``[N, 1]`` each, at ``state``."""

    def decision_reward(self, mean_step_reward: Tensor, terminated: Tensor) -> Tensor:
        """``[N, 1]`` reward of one env step from the mean of its control steps' rewards."""


class TrackingTask:
    """Track the reference (paper, Eq. 2), with the paper's crash rules.

    Per control step: ``r = alive_bonus - w_xy |e_xy| - w_z |e_z| - w_ff |u_ff| - w_dff |du_ff|``
    with ``e`` the true position minus the reference and ``u_ff`` the applied residual (0 for a
    row whose physics went non-finite): the wrench in N and N m, or a correction on the
    acceleration (``ResidualConfig.acts_on``) times the vehicle's mass, the force it asks for in N.
    Terminated: non-finite physics, tilt beyond ``crash_tilt_deg``, or ground contact later than
    ``takeoff_grace_s`` after arming (the climb's start). Truncated: the trajectory's end step.
    Per decision: the mean step reward plus ``crash_penalty`` if the episode terminated.
    ``device``: the env's, where the task's numbers are made once as tensors for the eager step
    (None: Python numbers, the same results, slower eagerly); a traced step combines the Python
    numbers (:mod:`.operands`).
    """

    def __init__(self, config: EnvConfig, device: torch.device | str | None = None):
        self.reward = reward = config.reward
        dt = config.timing.control_dt_s
        # ground contact ends an episode from this control step on (the arming step is the
        # trajectory library's: arm_time_s on the control clock)
        self.grace_steps = int(round(config.trajectories.arm_time_s / dt)) + int(round(reward.takeoff_grace_s / dt))
        self.cos_crash_tilt = math.cos(math.radians(reward.crash_tilt_deg))
        # N per unit of the applied residual: the effort weights are per N (and N m) of wrench
        self.ff_to_newton = config.vehicle.mass_kg if config.residual.acts_on == "acceleration" else 1.0
        self._numbers = _operands(self, None)
        self._tensors = self._numbers if device is None else _operands(self, device)

    def step_reward(self, params: TensorDict, before: TensorDict, after: TensorDict) -> Tensor:
        k = operands(self._tensors, self._numbers)
        err = entry(after, "body", "pos") - entry(after, "ref", "pos")
        ff, ff_prev = entry(after, "control", "ff"), entry(before, "control", "ff")
        reward = (
            k.alive_bonus
            - k.w_xy * norm(err[..., :2])
            - k.w_z * err[..., 2:].abs()
            - k.w_ff * norm(ff)
            - k.w_dff * norm(ff - ff_prev)
        )
        return torch.where(entry(after, "finite"), reward, k.zero)

    def done(self, params: TensorDict, state: TensorDict) -> tuple[Tensor, Tensor]:
        k = operands(self._tensors, self._numbers)
        pos, step = entry(state, "body", "pos"), entry(state, "step")
        upright = body_z_vertical(entry(state, "body", "quat")) > k.cos_crash_tilt
        grounded = (pos[..., 2:] <= k.zero) & (step > k.grace_steps).unsqueeze(-1)
        terminated = ~entry(state, "finite") | ~upright | grounded
        truncated = (step >= entry(params, "end_step")).unsqueeze(-1)
        return terminated, truncated

    def decision_reward(self, mean_step_reward: Tensor, terminated: Tensor) -> Tensor:
        k = operands(self._tensors, self._numbers)
        return mean_step_reward + torch.where(terminated, k.crash_penalty, k.zero)


class _Operands(NamedTuple):
    """The numbers a :class:`TrackingTask` combines with the state."""

    alive_bonus: Tensor | float
    w_xy: Tensor | float
    w_z: Tensor | float
    w_ff: Tensor | float
    w_dff: Tensor | float
    crash_penalty: Tensor | float
    zero: Tensor | float
    cos_crash_tilt: Tensor | float
    grace_steps: Tensor | int


def _operands(task: TrackingTask, device: torch.device | str | None) -> _Operands:
    """``task``'s numbers: Python numbers without ``device``, else 0-dim tensors on it (float32,
    the step counter's int64): an eager op converts a Python number operand at every use
    (``aten::_to_copy``), a tensor not at all, and the tensor holds the value that conversion
    gives, so the results are the same bits."""
    rw = task.reward
    # the mass folds into the effort weights: the wrench's reward keeps its operations and bits
    floats = (rw.alive_bonus, rw.w_xy, rw.w_z, rw.w_ff * task.ff_to_newton, rw.w_dff * task.ff_to_newton,
              rw.crash_penalty, 0.0, task.cos_crash_tilt)
    if device is None:
        return _Operands(*floats, task.grace_steps)
    return _Operands(*(torch.tensor(v, dtype=torch.float32, device=device) for v in floats),
                     torch.tensor(task.grace_steps, dtype=torch.int64, device=device))
