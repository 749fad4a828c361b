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
from typing import Protocol

import torch
from tensordict import TensorDict
from torch import Tensor

from ..config import EnvConfig
from .rotations import body_z_vertical, norm


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
    row whose physics went non-finite). Terminated: non-finite physics, tilt beyond
    ``crash_tilt_deg``, or ground contact later than ``takeoff_grace_s`` after arming (the
    climb's start). Truncated: the trajectory's end step. Per decision: the mean step reward plus
    ``crash_penalty`` if the episode terminated.
    """

    def __init__(self, config: EnvConfig):
        self.reward = reward = config.reward
        dt = config.timing.control_dt_s
        # ground contact ends an episode from this control step on (the arming step is the
        # trajectory library's: arm_time_s on the control clock)
        self.grace_steps = int(round(config.trajectories.arm_time_s / dt)) + int(round(reward.takeoff_grace_s / dt))
        self.cos_crash_tilt = math.cos(math.radians(reward.crash_tilt_deg))

    def step_reward(self, params: TensorDict, before: TensorDict, after: TensorDict) -> Tensor:
        rw = self.reward
        err = after["body", "pos"] - after["ref", "pos"]
        ff, ff_prev = after["control", "ff"], before["control", "ff"]
        reward = (
            rw.alive_bonus
            - rw.w_xy * norm(err[..., :2])
            - rw.w_z * err[..., 2:].abs()
            - rw.w_ff * norm(ff)
            - rw.w_dff * norm(ff - ff_prev)
        )
        return torch.where(after["finite"], reward, 0.0)

    def done(self, params: TensorDict, state: TensorDict) -> tuple[Tensor, Tensor]:
        pos = state["body", "pos"]
        upright = body_z_vertical(state["body", "quat"]) > self.cos_crash_tilt
        grounded = (pos[..., 2:] <= 0.0) & (state["step"] > self.grace_steps).unsqueeze(-1)
        terminated = ~state["finite"] | ~upright | grounded
        truncated = (state["step"] >= params["end_step"]).unsqueeze(-1)
        return terminated, truncated

    def decision_reward(self, mean_step_reward: Tensor, terminated: Tensor) -> Tensor:
        return mean_step_reward + torch.where(terminated, self.reward.crash_penalty, 0.0)

