"""Gymnasium entry points over the batched simulator, for Stable-Baselines3 and other gym users.

    import gymnasium as gym
    import quadwind_trl.gym  # registers the ids

    env = gym.make("QuadWind-Horizontal-v0")                            # one quadrotor: gymnasium.Env
    envs = gym.make_vec("QuadWind-Vertical-v0", num_envs=64)            # one batched simulator

Both wrap exactly the TorchRL stack of :func:`quadwind_trl.rl.envs.make_env` (estimator
transform, the paper's 23-dim observation, normalisation, clipping), so an observation here is
the observation the shipped policies and the TorchRL PPO see; the action is the residual wrench
in ``[-1, 1]^4`` (``0`` flies the PD baseline). One step is one policy decision (0.1 s of flight).

The normalisation is frozen: by default at the shipped policy's statistics for the regime (what a
gym agent needs: fixed inputs, and gymnasium's determinism checks), or at ``vecnorm_state``.
The vector env resets finished sub-envs in the same step (``AutoresetMode.SAME_STEP``, as
TorchRL's ``step_and_maybe_reset``): the last observation of the finished episode is in
``infos["final_obs"]``.
"""
from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from tensordict import TensorDictBase

from .estimator import load_estimator
from .keys import OBSERVATION_KEY
from .manifest import CHECKPOINT_DIR
from .rl.envs import Regime, WindInput, check_regime, make_env, policy_env_settings
from .validation import check_action, load_checkpoint

ENV_IDS = {"horizontal": "QuadWind-Horizontal-v0", "vertical": "QuadWind-Vertical-v0"}


def shipped_policy_inputs(regime: Regime, estimator) -> dict:
    """What the shipped policy for ``regime`` saw: its observation statistics and the env settings
    it trained with (:func:`~quadwind_trl.rl.envs.policy_env_settings`: the EMA time constant on
    its wind estimate, how often the estimator ran, the inputs it trained without), as ``make_env``
    keywords."""
    check_regime(regime)  # before the regime names a file
    payload = load_checkpoint(CHECKPOINT_DIR / f"policy_{regime}.pt", "policy")
    return {"vecnorm_state": payload["vecnorm"], **policy_env_settings(payload["env_spec"], estimator)}


class _BatchedStack:
    """The TorchRL stack both gym classes drive: numpy in, numpy out, no autograd."""

    def __init__(self, regime: Regime, num_envs: int, wind_input: WindInput, estimator: str | None,
                 vecnorm_state: dict | None, obs_clip: float, seed: int, env_kwargs: dict[str, Any]):
        bundle = None if wind_input == "truth" else load_estimator(regime, estimator)
        # the shipped policy's normalisation comes with the filter it was trained behind (env_kwargs
        # may still set ema_tau_s); a given vecnorm_state leaves the filter to env_kwargs
        shipped = shipped_policy_inputs(regime, bundle) if vecnorm_state is None else {"vecnorm_state": vecnorm_state}
        self.env = make_env(regime, bundle, num_envs, wind_input=wind_input, seed=seed, obs_clip=obs_clip,
                            **(shipped | env_kwargs))
        self.num_envs = num_envs
        # the paper's 23 inputs, or more with env_kwargs such as memory_frames or base_state_inputs
        self.obs_dim = self.env.observation_spec[OBSERVATION_KEY].shape[-1]
        # 4 (the residual on the wrench) or 3 (on the acceleration: env_kwargs' config)
        self.action_dim = self.env.action_spec.shape[-1]
        self.td: TensorDictBase | None = None

    def reset(self, seed: int | None, scenario: TensorDictBase | None) -> np.ndarray:
        if seed is not None:
            self.env.set_seed(seed)
        self.td = self.env.reset(**({"scenario": scenario} if scenario is not None else {}))
        return self._obs(self.td)

    @torch.no_grad()
    def step(self, action: np.ndarray) -> tuple[TensorDictBase, TensorDictBase]:
        """One decision for every sub-env, ``action`` ``[num_envs, action_dim]`` (the env checks the shape):
        ``(transition, next root)``, finished rows already reset."""
        action = torch.as_tensor(np.asarray(action, dtype=np.float32))
        check_action(action, self.num_envs, self.action_dim)  # before the tensordict's own batch check
        self.td.set("action", action)
        transition, self.td = self.env.step_and_maybe_reset(self.td)
        return transition, self.td

    @staticmethod
    def _obs(td: TensorDictBase) -> np.ndarray:
        return td.get(OBSERVATION_KEY).numpy().astype(np.float32, copy=True)


def _spaces(obs_clip: float, obs_dim: int, action_dim: int,
            num_envs: int | None = None) -> tuple[spaces.Box, spaces.Box]:
    shape = (obs_dim,) if num_envs is None else (num_envs, obs_dim)
    ashape = (action_dim,) if num_envs is None else (num_envs, action_dim)
    return (spaces.Box(-obs_clip, obs_clip, shape, np.float32), spaces.Box(-1.0, 1.0, ashape, np.float32))


class QuadWindVectorEnv(gymnasium.vector.VectorEnv):
    """``num_envs`` quadrotors in one batched simulator (no process per env)."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, regime: Regime = "horizontal", num_envs: int = 8, *, wind_input: WindInput = "estimate",
                 estimator: str | None = None, vecnorm_state: dict | None = None, obs_clip: float = 10.0,
                 seed: int = 0, **env_kwargs):
        self.stack = _BatchedStack(regime, num_envs, wind_input, estimator, vecnorm_state, obs_clip, seed, env_kwargs)
        self.num_envs = num_envs
        obs_dim = self.stack.obs_dim
        self.single_observation_space, self.single_action_space = _spaces(obs_clip, obs_dim, self.stack.action_dim)
        self.observation_space, self.action_space = _spaces(obs_clip, obs_dim, self.stack.action_dim, num_envs)
        self.regime = regime

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """``options={"scenario": make_scenarios(num_envs, ...)}`` replays given episodes."""
        super().reset(seed=seed)
        return self.stack.reset(seed, (options or {}).get("scenario")), {}

    def step(self, actions):
        transition, root = self.stack.step(actions)
        nxt = transition.get("next")
        terminated = nxt.get("terminated").reshape(-1).numpy().copy()
        truncated = nxt.get("truncated").reshape(-1).numpy().copy()
        infos: dict[str, Any] = {}
        done = terminated | truncated
        if done.any():
            infos["final_obs"] = np.where(done[:, None], _BatchedStack._obs(nxt), 0.0).astype(np.float32)
            infos["_final_obs"] = done.copy()
        reward = nxt.get("reward").reshape(-1).numpy().astype(np.float64)
        return _BatchedStack._obs(root), reward, terminated, truncated, infos


class QuadWindEnv(gymnasium.Env):
    """One quadrotor as a ``gymnasium.Env`` (a batch of one of the same simulator)."""

    metadata = {"render_modes": []}

    def __init__(self, regime: Regime = "horizontal", *, wind_input: WindInput = "estimate", estimator: str | None = None,
                 vecnorm_state: dict | None = None, obs_clip: float = 10.0, seed: int = 0, **env_kwargs):
        self.stack = _BatchedStack(regime, 1, wind_input, estimator, vecnorm_state, obs_clip, seed, env_kwargs)
        self.observation_space, self.action_space = _spaces(obs_clip, self.stack.obs_dim, self.stack.action_dim)
        self.regime = regime

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """``options={"scenario": make_scenarios(1, ...)}`` replays a given episode."""
        super().reset(seed=seed)
        return self.stack.reset(seed, (options or {}).get("scenario"))[0], {}

    def step(self, action):
        transition, _ = self.stack.step(np.asarray(action)[None])
        # the episode's own last observation (the stack has already started the next one)
        nxt = transition.get("next")
        obs = _BatchedStack._obs(nxt)[0]
        return obs, float(nxt.get("reward")), bool(nxt.get("terminated")), bool(nxt.get("truncated")), {}


def _register() -> None:
    for regime, env_id in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                id=env_id,
                entry_point="quadwind_trl.gym:QuadWindEnv",
                vector_entry_point="quadwind_trl.gym:QuadWindVectorEnv",
                kwargs={"regime": regime},
            )


_register()
