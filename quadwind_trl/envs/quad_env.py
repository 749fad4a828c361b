"""``QuadWindEnv``: the batched quadrotor-in-turbulence simulator as a native TorchRL env."""
from __future__ import annotations

import contextlib
import functools
from dataclasses import dataclass
from typing import Literal

import torch
from tensordict import NestedKey, TensorDict, TensorDictBase, is_tensor_collection
from torchrl.data import Binary, Bounded, Composite, Unbounded
from torchrl.envs import EnvBase

from ..config import EnvConfig
from ..keys import BASE_STATE_KEY, BASE_WIND_KEY, MEAS_KEY, MONITOR_KEY, RESIDUAL_ENTRY
from ..validation import check_action
from .scenarios import RegimeRanges, make_scenarios, random_scenarios, validate_scenarios
from .sensors import INSTRUMENTS
from .control_step import CompiledControlStep, held_control_steps
from .controller import BaseController
from .simulator import QuadSimulator
from .task import Task, TrackingTask
from .tensordicts import entry
from .trajectories import HORIZONTAL, Reference, trajectory_ids


@dataclass(frozen=True)
class ScenarioSampler:
    """Draws a fresh episode spec for every sub-env that resets without one.

    Draws are counter-based: sub-env ``i``'s ``e``-th episode is a function of
    ``(env seed, i, e)`` only, so a training run is reproducible whatever resets when.
    ``start="pattern"`` starts airborne at the beginning of the pattern (skipping the climb).
    """

    ranges: RegimeRanges = RegimeRanges()
    trajectories: tuple[str, ...] = HORIZONTAL
    start: Literal["ground", "pattern"] = "ground"

    def __post_init__(self):
        trajectory_ids(self.trajectories)  # fails early on an unknown name, listing the registered
        if self.start not in ("ground", "pattern"):
            raise ValueError(f"ScenarioSampler.start={self.start!r}; allowed: 'ground', 'pattern'")

    def __call__(self, key: torch.Tensor, counter: torch.Tensor) -> TensorDict:
        ids = trajectory_ids(self.trajectories, key.device)
        sc = random_scenarios(key, counter, self.ranges, ids)
        if self.start == "pattern":
            sc["start_step"] = torch.full_like(sc["start_step"], -1)
        return sc


# observation entry -> (simulator state entry it shows, width): the float entries of the
# observation are views of the state, declared once for the specs and the observation (those of
# the residual on the wrench: state_views gives the residual's entry its name and width)
_STATE_VIEWS: dict[NestedKey, tuple[NestedKey, int]] = {
    "ref_pos": (("ref", "pos"), 3),
    "ref_vel": (("ref", "vel"), 3),
    "ref_acc": (("ref", "acc"), 3),
    "ref_yaw": (("ref", "yaw"), 1),
    "nav_pos": (("nav", "pos"), 3),
    "nav_vel": (("nav", "vel"), 3),
    "pd_wrench": (("control", "pd_wrench"), 4),
    "ff_wrench": (("control", "ff"), 4),
    "cmd_wrench": (("control", "cmd"), 4),
    "tilt_cmd": (("control", "tilt_cmd"), 1),
    ("truth", "pos"): (("body", "pos"), 3),
    ("truth", "vel"): (("body", "vel"), 3),
    ("truth", "quat"): (("body", "quat"), 4),
    ("truth", "omega"): (("body", "omega"), 3),
    ("truth", "wind"): (("wind", "total"), 3),  # the air velocity the vehicle flies in
    ("truth", "mean_wind"): (("wind", "mean"), 3),  # turbulence-free
}


def state_views(config: EnvConfig) -> dict[NestedKey, tuple[NestedKey, int]]:
    """The observation's views of the state for ``config``: the applied residual is
    ``RESIDUAL_ENTRY[acts_on]`` (``ff_wrench`` [4] or ``ff_acc`` [3]), in its place."""
    residual = config.residual
    if residual.acts_on == "wrench":
        return _STATE_VIEWS
    ff = RESIDUAL_ENTRY["wrench"]
    return dict((RESIDUAL_ENTRY[residual.acts_on], (view[0], residual.channels)) if key == ff else (key, view)
                for key, view in _STATE_VIEWS.items())


def _vec(n: int, dim: int, device, dtype=torch.float32) -> Unbounded:
    return Unbounded(shape=(n, dim), device=device, dtype=dtype)


def _leaf_keys(td: TensorDict) -> list[NestedKey]:
    """The leaf keys of ``td``, sorted: a nested key by its path, beside the plain ones."""
    return sorted(td.keys(True, True), key=lambda k: (k,) if isinstance(k, str) else k)


def _ordinary(value):
    """``value`` (a tensor, TensorDict or tuple of them) with every tensor made in inference mode,
    or viewing one made outside it there, copied into an ordinary tensor (the same values and
    strides): an inference tensor cannot be saved for a backward pass, nor written in place."""
    if isinstance(value, tuple):
        return tuple(_ordinary(v) for v in value)
    if is_tensor_collection(value):
        return TensorDict._new_unsafe({k: _ordinary(v) for k, v in value.items()}, batch_size=value.batch_size,
                                      device=value.device)
    return value.clone() if value.is_inference() or value._is_view() else value


# QuadWindEnv(compile_step=...): eager, compiled with the batch dimension symbolic (True is
# "dynamic"), or compiled with static sizes
COMPILE_STEP_CHOICES = (False, True, "static", "dynamic")


class QuadWindEnv(EnvBase):
    """A batch of quadrotors flying reference trajectories through wind and turbulence.

    The action is the residual wrench in ``[-1, 1]^4`` (collective thrust, roll, pitch, yaw
    torques), scaled, smoothed, slew-limited and added to the base controller's output
    (``ControllerConfig``: the paper's PD cascade by default, or PID, wind feed-forward or a
    disturbance observer; :mod:`quadwind_trl.envs.controller`): ``action = 0`` is the base law.
    With ``ResidualConfig.acts_on="acceleration"`` it is ``[-1, 1]^3`` (forward, left, up in the
    reference heading's frame), scaled, smoothed, slew-limited and added to the base law's
    desired acceleration instead, from the next control step on; ``action = 0`` is again the base law.
    A wind feed-forward base law also takes ``base_wind_ne`` [2] (north, east, m/s;
    :data:`~quadwind_trl.keys.BASE_WIND_KEY`) as an input of every step, beside the action
    (``transforms.BaseWindInput`` gives it from the wind estimate). One step is ``TimingConfig.hold_control_steps`` 10 ms control steps (5
    physics substeps each) under the same action; the reward is the task's (default
    :class:`~quadwind_trl.envs.task.TrackingTask`: Eq. (2)) averaged over them.

    Observations (all batched ``[N, ...]``, frames in :mod:`quadwind_trl.envs`):

    * ``meas``: the held sensor measurements, one named entry per instrument
      (:data:`~quadwind_trl.envs.sensors.INSTRUMENTS`): ``gps_pos``, ``gps_vel`` [3] (ENU, m,
      m/s), ``baro_alt`` [1] (m), ``attitude`` [3] (roll, pitch, yaw; rad), ``gyro`` [3] (body,
      rad/s), ``accel`` [3] (body specific force, m/s^2);
    * ``ref_pos``, ``ref_vel``, ``ref_acc`` [3], ``ref_yaw`` [1]: the reference now;
    * ``nav_pos``, ``nav_vel`` [3]: the autopilot's navigation solution that the PD flies on
      (``ControllerConfig.feedback``: the truth, the raw sensors, or the navigation filter);
    * ``pos_error`` [3]: ``nav_pos`` minus the reference: the tracking error the vehicle perceives;
    * ``pd_wrench`` [4]: the PD output the next action is added to; ``ff_wrench`` [4]: the
      correction applied over the last step (on the acceleration: ``ff_acc`` [3], m/s^2, forward,
      left, up, the correction the next ``pd_wrench`` holds); ``cmd_wrench`` [4]: the total command applied;
    * ``tilt_cmd`` [1] (rad), ``tilt_saturated`` [1]: the PD's commanded tilt and its limit flag;
    * ``monitor_active`` [1] (only with ``ResidualConfig.monitor`` on): the runtime monitor held
      the residual at zero over the last control step (:mod:`quadwind_trl.envs.monitor`);
    * ``base`` (only for a base law with state: integral action or a force estimate): the law's
      state after the step, one entry per :meth:`~quadwind_trl.envs.controller.BaseController.init_state`
      entry (``integral`` [3] m s, ``force_hat`` [3] N, ``thrust_hat`` [1] N, ``vel_hat`` [3] m/s; world ENU);
    * ``step`` [1]: the control-step index (int64; the 10 Hz log ticks where it is a multiple of 10);
    * ``truth``: simulator truth for labels and diagnostics (``pos``, ``vel``, ``quat``, ``omega``,
      ``wind`` the total air velocity, ``mean_wind`` the turbulence-free mean).

    Episodes: ``env.reset()`` draws scenarios from ``scenario_sampler``; to replay given
    episodes, pass them as a keyword: ``env.reset(scenario=make_scenarios(N, ...))`` (with a
    ``"_reset"`` tensordict, ``env.reset(td, scenario=...)``, to restart only some rows). A keyword
    rather than a tensordict entry because TorchRL's partial-reset merge overwrites, in place,
    input entries the env does not return, and ``TransformedEnv`` drops them. With the default
    task, episodes terminate on a crash (ground contact after take-off, tilt beyond
    ``RewardConfig.crash_tilt_deg``, non-finite state: reward ``-100``) and are truncated at the
    trajectory's end; ``task=`` replaces reward and termination (:mod:`quadwind_trl.envs.task`).

    ``compile_step``: ``False`` runs each control step eagerly; ``True`` (or ``"dynamic"``)
    through ``torch.compile`` with the batch dimension symbolic, one compilation per
    configuration for every batch size and partial reset; ``"static"`` with static sizes, one
    compilation per configuration and batch size. Compiled code is kept on disk between
    processes (:func:`~quadwind_trl.envs.compile_cache.compile_cache_dir`;
    :mod:`quadwind_trl.envs.control_step`).

    The simulator's per-episode ``params`` and dynamic ``state`` (TensorDicts, keys in
    :mod:`quadwind_trl.envs.simulator`) are ``env.params`` and ``env.state``.
    """

    _batch_locked = True

    def __init__(
        self,
        config: EnvConfig | None = None,
        *,
        batch_size: torch.Size | tuple[int, ...] | list[int] = (1,),
        device: torch.device | str | None = None,
        scenario_sampler: ScenarioSampler | None = None,
        seed: int = 0,
        compile_step: bool | str = False,
        task: Task | None = None,
        first_row: int = 0,
        controller: BaseController | None = None,
    ):
        batch_size = torch.Size(batch_size)
        if len(batch_size) != 1 or batch_size[0] < 1:
            raise ValueError(f"QuadWindEnv.batch_size={list(batch_size)}; allowed: [N] with N >= 1 (one row per sub-env)")
        if first_row < 0:
            raise ValueError(f"QuadWindEnv.first_row={first_row}; allowed: >= 0")
        # this env's rows are rows first_row, first_row + 1, ... of a larger batch (one worker of
        # envs.parallel): each row's episodes are drawn from its global row index
        self._first_row = int(first_row)
        super().__init__(device=device if device is not None else "cpu", batch_size=batch_size)
        self.config = (config or EnvConfig()).validate()
        self.sim = QuadSimulator(self.config, self.device, controller=controller)
        self._views = state_views(self.config)
        self.scenario_sampler = scenario_sampler or ScenarioSampler()
        if task is not None:
            missing = [m for m in ("step_reward", "done", "decision_reward") if not callable(getattr(task, m, None))]
            if missing:
                raise TypeError(f"task={type(task).__name__} lacks {missing}: a task needs the methods of envs.task.Task")
        self.task = task if task is not None else TrackingTask(self.config, self.device)
        if compile_step not in COMPILE_STEP_CHOICES:
            raise ValueError(f"QuadWindEnv.compile_step={compile_step!r}; allowed: {', '.join(map(repr, COMPILE_STEP_CHOICES))}")
        # the hold's control steps under one action, from the decision's running totals
        self._hold = (CompiledControlStep(self.sim, self.task, dynamic=compile_step != "static") if compile_step
                      else functools.partial(held_control_steps, self.sim, self.task))
        self._compiled = bool(compile_step)
        # a decision's running totals (reward sum, control steps, terminated, truncated) start
        # from these: made once, as a step only makes new tensors from them
        n, dev = self.batch_size[0], self.device
        flag = lambda: torch.zeros(n, 1, dtype=torch.bool, device=dev)  # noqa: E731
        self._no_totals = (torch.zeros(n, 1, device=dev), torch.zeros(n, 1, device=dev), flag(), flag())
        self.params: TensorDict | None = None
        self.state: TensorDict | None = None
        self._make_specs()
        self.set_seed(seed)

    def _make_specs(self) -> None:
        n, dev = self.batch_size[0], self.device
        spec = Composite({MEAS_KEY: Composite({i.name: _vec(n, i.width, dev) for i in INSTRUMENTS}, shape=(n,), device=dev),
                          "truth": Composite(shape=(n,), device=dev)}, shape=(n,), device=dev)
        for key, (_, width) in self._views.items():
            spec[key] = _vec(n, width, dev)
        spec["pos_error"] = _vec(n, 3, dev)
        spec["tilt_saturated"] = Binary(n=1, shape=(n, 1), device=dev, dtype=torch.bool)
        spec["step"] = _vec(n, 1, dev, torch.int64)
        if self.config.residual.monitor is not None:
            spec[MONITOR_KEY] = Binary(n=1, shape=(n, 1), device=dev, dtype=torch.bool)
        base = self.sim.controller.init_state(1, dev)
        if base is not None:  # the base law's state (a policy may read it: transforms.PolicyObservation)
            spec[BASE_STATE_KEY] = Composite({k: _vec(n, v.shape[-1], dev) for k, v in base.items()}, shape=(n,), device=dev)
        self.observation_spec = spec
        self.action_spec = Bounded(low=-1.0, high=1.0, shape=(n, self.config.residual.channels), device=dev)
        if self.sim.controller.needs_wind:
            self.state_spec = Composite({BASE_WIND_KEY: _vec(n, 2, dev)}, shape=(n,), device=dev)
        self.reward_spec = Unbounded(shape=(n, 1), device=dev)
        flag = lambda: Binary(n=1, shape=(n, 1), device=dev, dtype=torch.bool)  # noqa: E731
        self.done_spec = Composite(done=flag(), terminated=flag(), truncated=flag(), shape=(n,), device=dev)

    # --- EnvBase hooks --------------------------------------------------------------------------

    def _set_seed(self, seed: int | None) -> None:
        seed = 0 if seed is None else int(seed)
        n = self.batch_size[0]
        self._row_keys = seed * 1_000_003 + self._first_row + torch.arange(n, device=self.device, dtype=torch.int64)
        self._episode_count = torch.zeros(n, dtype=torch.int64, device=self.device)

    def _reset(self, tensordict: TensorDictBase | None = None, scenario: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        n = self.batch_size[0]
        mask = tensordict.get("_reset", None) if tensordict is not None else None
        if mask is None or self.state is None:
            mask = torch.ones(n, dtype=torch.bool, device=self.device)
        mask = mask.reshape(n)
        if scenario is not None:  # a user's spec: checked once per reset (the sampler's draws are valid by construction)
            if tuple(scenario.batch_size) != (n,):
                raise ValueError(f"scenario has batch size {list(scenario.batch_size)}, expected [{n}] (one row per sub-env)")
            validate_scenarios(scenario)
        # the one host sync of a reset: which rows restart, so that only those rows are drawn and built
        rows = mask.nonzero().squeeze(-1)
        if rows.numel() > 0:
            if scenario is None:
                scenario = self.scenario_sampler(self._row_keys[rows], self._episode_count[rows])
            else:
                scenario = scenario[rows]
            self._episode_count = self._episode_count + mask.to(torch.int64)
            self.params, self.state = self.sim.reset(self.params, self.state, scenario, None if rows.numel() == n else rows)
        out = self._observation(self.state)
        out.update(self.full_done_spec.zero())
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get("action", None)
        check_action(action, self.batch_size[0], self.config.residual.channels)
        wind_ne = None
        if self.sim.controller.needs_wind:
            wind_ne = tensordict.get(BASE_WIND_KEY, None)
            if wind_ne is None:
                raise KeyError(f"this env's base controller flies on a wind estimate: the step's input needs "
                               f"{BASE_WIND_KEY!r} [N, 2] (north, east, m/s) beside the action "
                               "(transforms.BaseWindInput writes it from the wind estimate)")
        # eagerly, the held steps run in inference mode: no autograd bookkeeping per op (a fifth of
        # the eager step at small batches); what they return leaves it as ordinary tensors. Not
        # for an action that asks for gradients through the simulator
        inference = not (self._compiled or torch.is_inference_mode_enabled() or action.requires_grad)
        with torch.inference_mode() if inference else contextlib.nullcontext():
            state, reward, steps, terminated, truncated = self._hold(
                self.params, self.state, action, wind_ne, *self._no_totals, count=self.config.timing.hold_control_steps)
        if inference:
            state, reward, steps, terminated, truncated = _ordinary((state, reward, steps, terminated, truncated))
        self.state = state
        return self._observation(state, reward=self.task.decision_reward(reward / steps, terminated),
                                 terminated=terminated, truncated=truncated, done=terminated | truncated)

    # --- helpers --------------------------------------------------------------------------------

    def _observation(self, s: TensorDict, **extra: torch.Tensor) -> TensorDict:
        """The observation of state ``s``, with the entries ``extra`` (a step's reward and flags)."""
        entries = {
            MEAS_KEY: dict(entry(s, "sensors", MEAS_KEY).items()),
            "pos_error": entry(s, "nav", "pos") - entry(s, "ref", "pos"),
            "tilt_saturated": entry(s, "control", "tilt_saturated"),
            "step": entry(s, "step").unsqueeze(-1),
        }
        for key, (source, _) in self._views.items():
            *parents, name = (key,) if isinstance(key, str) else key
            node = entries
            for parent in parents:
                node = node.setdefault(parent, {})
            node[name] = entry(s, *source)
        if self.config.residual.monitor is not None:
            entries[MONITOR_KEY] = entry(s, "control", "monitor_left") > 0
        if BASE_STATE_KEY in s.keys():
            entries[BASE_STATE_KEY] = dict(entry(s, BASE_STATE_KEY).items())
        entries.update(extra)
        # without the constructor's per-entry checks (they cost more than the step's arithmetic at
        # small batches): every entry is the simulator's, of batch [N] on this env's device
        return TensorDict._new_unsafe(entries, batch_size=self.batch_size, device=self.device)

    def reference_at(self, step: torch.Tensor) -> Reference:
        """The reference of each running episode at control step ``step`` (``[N]`` int64; e.g. a
        second ahead of now, which a planning controller may read): the trajectory the episode flies,
        as the simulator evaluates it every control step (past its end, its last sample)."""
        scenario = entry(self.params, "scenario")
        return self.sim.trajectories.reference(entry(scenario, "traj_id"), step, entry(self.params, "pattern_start"),
                                               entry(scenario, "altitude_m"))

    def sim_state(self, key: NestedKey) -> torch.Tensor:
        """A copy of one entry of the simulator's state or, failing that, of its per-episode
        params (e.g. ``"pattern_start"``, ``("body", "rotor")``, ``("wind", "phase")``)."""
        for td in (self.state, self.params):
            value = td.get(key, None)
            if value is not None:
                return value.clone()
        raise KeyError(f"{key!r} is neither a simulator state nor a params entry; state: "
                       f"{_leaf_keys(self.state)}, params: {_leaf_keys(self.params)}")

    def scenario(self) -> TensorDict:
        """The scenarios of the episodes now running (a copy)."""
        return make_scenarios(self.batch_size[0], device=self.device, check=False, **self.params["scenario"].to_dict())
