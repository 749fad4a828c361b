"""``QuadWindEnv``: the batched quadrotor-in-turbulence simulator as a native TorchRL env."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Binary, Bounded, Composite, Unbounded
from torchrl.envs import EnvBase

from ..config import EnvConfig
from ..validation import check_action, validate_scenarios
from .scenarios import SCENARIO_FIELDS, RegimeRanges, make_scenarios, random_scenarios
from .sensors import NUM_SENSOR_CHANNELS
from .simulator import QuadSimulator, merge_rows
from .trajectories import HORIZONTAL, trajectory_ids


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


def _vec(n: int, dim: int, device, dtype=torch.float32) -> Unbounded:
    return Unbounded(shape=(n, dim), device=device, dtype=dtype)


class QuadWindEnv(EnvBase):
    """A batch of quadrotors flying reference trajectories through wind and turbulence.

    The action is the residual wrench in ``[-1, 1]^4`` (collective thrust, roll, pitch, yaw
    torques), scaled, smoothed, slew-limited and added to the PD cascade's output: ``action = 0``
    is the PD baseline. One step is ``ResidualConfig.hold_control_steps`` 10 ms control steps (5
    physics substeps each) under the same action; the reward is Eq. (2) averaged over them.

    Observations (all batched ``[N, ...]``, frames in :mod:`quadwind_trl.envs`):

    * ``meas`` [16]: the held sensor measurements (``SENSOR_CHANNELS``);
    * ``ref_pos``, ``ref_vel``, ``ref_acc`` [3], ``ref_yaw`` [1]: the reference now;
    * ``nav_pos``, ``nav_vel`` [3]: the autopilot's navigation solution that the PD flies on
      (``ControllerConfig.feedback``: the truth, the raw sensors, or the navigation filter);
    * ``pos_error`` [3]: ``nav_pos`` minus the reference: the tracking error the vehicle perceives;
    * ``pd_wrench`` [4]: the PD output the next action is added to; ``ff_wrench`` [4]: the
      correction applied over the last step; ``cmd_wrench`` [4]: the total command applied;
    * ``tilt_cmd`` [1] (rad), ``tilt_saturated`` [1]: the PD's commanded tilt and its limit flag;
    * ``step`` [1]: the control-step index (int64; the 10 Hz log ticks where it is a multiple of 10);
    * ``truth``: simulator truth for labels and diagnostics (``pos``, ``vel``, ``quat``, ``omega``,
      ``wind`` the total air velocity, ``mean_wind`` the turbulence-free mean).

    Episodes: ``env.reset()`` draws scenarios from ``scenario_sampler``; to replay given
    episodes, pass them as a keyword: ``env.reset(scenario=make_scenarios(N, ...))`` (with a
    ``"_reset"`` tensordict, ``env.reset(td, scenario=...)``, to restart only some rows). A keyword
    rather than a tensordict entry because TorchRL's partial-reset merge overwrites, in place,
    input entries the env does not return, and ``TransformedEnv`` drops them. Episodes terminate on a crash (ground contact
    after take-off, tilt beyond ``RewardConfig.crash_tilt_deg``, non-finite state: reward
    ``-100``) and are truncated at the trajectory's end.
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
        compile_step: bool = False,
    ):
        batch_size = torch.Size(batch_size)
        if len(batch_size) != 1:
            raise ValueError(f"QuadWindEnv takes a 1-D batch_size [N], got {list(batch_size)}")
        super().__init__(device=device if device is not None else "cpu", batch_size=batch_size)
        self.config = (config or EnvConfig()).validate()
        self.sim = QuadSimulator(self.config, self.device)
        self.scenario_sampler = scenario_sampler or ScenarioSampler()
        self._sim_step = torch.compile(self.sim.step, dynamic=False) if compile_step else self.sim.step
        self.state: dict[str, torch.Tensor] | None = None
        self._make_specs()
        self.set_seed(seed)

    def _make_specs(self) -> None:
        n, dev = self.batch_size[0], self.device
        self.observation_spec = Composite(
            meas=_vec(n, NUM_SENSOR_CHANNELS, dev),
            ref_pos=_vec(n, 3, dev),
            ref_vel=_vec(n, 3, dev),
            ref_acc=_vec(n, 3, dev),
            ref_yaw=_vec(n, 1, dev),
            nav_pos=_vec(n, 3, dev),
            nav_vel=_vec(n, 3, dev),
            pos_error=_vec(n, 3, dev),
            pd_wrench=_vec(n, 4, dev),
            ff_wrench=_vec(n, 4, dev),
            cmd_wrench=_vec(n, 4, dev),
            tilt_cmd=_vec(n, 1, dev),
            tilt_saturated=Binary(n=1, shape=(n, 1), device=dev, dtype=torch.bool),
            step=_vec(n, 1, dev, torch.int64),
            truth=Composite(
                pos=_vec(n, 3, dev),
                vel=_vec(n, 3, dev),
                quat=_vec(n, 4, dev),
                omega=_vec(n, 3, dev),
                wind=_vec(n, 3, dev),
                mean_wind=_vec(n, 3, dev),
                shape=(n,),
                device=dev,
            ),
            shape=(n,),
            device=dev,
        )
        self.action_spec = Bounded(low=-1.0, high=1.0, shape=(n, 4), device=dev)
        self.reward_spec = Unbounded(shape=(n, 1), device=dev)
        flag = lambda: Binary(n=1, shape=(n, 1), device=dev, dtype=torch.bool)  # noqa: E731
        self.done_spec = Composite(done=flag(), terminated=flag(), truncated=flag(), shape=(n,), device=dev)

    # --- EnvBase hooks --------------------------------------------------------------------------

    def _set_seed(self, seed: int | None) -> None:
        seed = 0 if seed is None else int(seed)
        n = self.batch_size[0]
        self._row_keys = seed * 1_000_003 + torch.arange(n, device=self.device, dtype=torch.int64)
        self._episode_count = torch.zeros(n, dtype=torch.int64, device=self.device)

    def _reset(self, tensordict: TensorDictBase | None = None, scenario: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        n = self.batch_size[0]
        mask = tensordict.get("_reset", None) if tensordict is not None else None
        mask = torch.ones(n, dtype=torch.bool, device=self.device) if mask is None else mask.reshape(n)
        if scenario is None:
            scenario = self.scenario_sampler(self._row_keys, self._episode_count)
        else:  # a user's spec: checked once per reset (the sampler's draws are valid by construction)
            if tuple(scenario.batch_size) != (n,):
                raise ValueError(f"scenario has batch size {list(scenario.batch_size)}, expected [{n}] (one row per sub-env)")
            validate_scenarios(scenario)
        self._episode_count = self._episode_count + mask.to(torch.int64)
        self.state = self.sim.reset(self.state, scenario, mask)
        out = self._observation(self.state)
        out.update(self.full_done_spec.zero())
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get("action", None)
        check_action(action, self.batch_size[0], 4)
        state = self._sim_step(self.state, action)
        reward, steps = state["reward"], torch.ones_like(state["reward"])
        # a held action: rows that end inside the hold stay frozen at their last state
        terminated, truncated = state["terminated"], (state["step"] >= state["end_step"]).unsqueeze(-1)
        for _ in range(self.config.residual.hold_control_steps - 1):
            running = ~(terminated | truncated)
            state = merge_rows(running.reshape(-1), self._sim_step(state, action), state)
            reward = reward + torch.where(running, state["reward"], 0.0)
            steps = steps + running.to(steps.dtype)
            terminated, truncated = state["terminated"], (state["step"] >= state["end_step"]).unsqueeze(-1)
        self.state = state
        out = self._observation(state)
        # Eq. (2) averaged over the held control steps, the crash penalty once
        out.set("reward", reward / steps + torch.where(terminated, self.config.reward.crash_penalty, 0.0))
        out.set("terminated", terminated)
        out.set("truncated", truncated)
        out.set("done", terminated | truncated)
        return out

    # --- helpers --------------------------------------------------------------------------------

    def _observation(self, s: dict[str, torch.Tensor]) -> TensorDict:
        return TensorDict(
            {
                "meas": s["meas"],
                "ref_pos": s["ref_pos"],
                "ref_vel": s["ref_vel"],
                "ref_acc": s["ref_acc"],
                "ref_yaw": s["ref_yaw"],
                "nav_pos": s["nav.pos"],
                "nav_vel": s["nav.vel"],
                "pos_error": s["nav.pos"] - s["ref_pos"],
                "pd_wrench": s["pd_wrench"],
                "ff_wrench": s["ff"],
                "cmd_wrench": s["cmd"],
                "tilt_cmd": s["tilt_cmd"],
                "tilt_saturated": s["tilt_saturated"],
                "step": s["step"].unsqueeze(-1),
                "truth": {
                    "pos": s["pos"],
                    "vel": s["vel"],
                    "quat": s["quat"],
                    "omega": s["omega"],
                    "wind": s["wind_total"],
                    "mean_wind": s["wind_mean"],
                },
            },
            batch_size=self.batch_size,
            device=self.device,
        )

    def sim_state(self, key: str) -> torch.Tensor:
        """A copy of one entry of the simulator state (e.g. ``"pattern_start"``, ``"rotor"``)."""
        return self.state[key].clone()

    def scenario(self) -> TensorDict:
        """The scenarios of the episodes now running (a copy)."""
        return make_scenarios(
            self.batch_size[0], device=self.device, check=False, **{k: self.state[f"scenario.{k}"] for k in SCENARIO_FIELDS}
        )
