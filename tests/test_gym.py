"""The gymnasium adapter: registered ids, gymnasium's env checker, the vector env's batching and
same-step autoreset, the observation equal to the TorchRL stack's, and the SB3 example."""
from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

import quadwind_trl.gym as qgym
from quadwind_trl.config import TrajectoryConfig
from quadwind_trl.regimes import regime_config

ROOT = Path(__file__).resolve().parent.parent


def _short(regime: str) -> dict:
    traj = replace(TrajectoryConfig(), horizontal_duration_s=2.0, vertical_top_m=10.0, vertical_hold_s=0.5)
    return {"config": replace(regime_config(regime), trajectories=traj), "start": "pattern", "compile_step": False}


@pytest.mark.parametrize("regime", ["horizontal", "vertical"])
def test_registered_env_passes_gymnasium_check_env(regime):
    env = gym.make(qgym.ENV_IDS[regime], **_short(regime))
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=3)
    assert obs.shape == (23,) and obs.dtype == np.float32
    steps, done = 0, False
    while not done:
        obs, reward, terminated, truncated, _ = env.step(np.zeros(4, np.float32))
        assert env.observation_space.contains(obs) and isinstance(reward, float)
        done, steps = terminated or truncated, steps + 1
    assert truncated and steps < 150  # a short flight ends by truncation, not a crash


def test_vector_env_batches_and_resets_in_the_same_step():
    envs = gym.make_vec(qgym.ENV_IDS["horizontal"], num_envs=3, **_short("horizontal"))
    assert isinstance(envs.unwrapped, gym.vector.VectorEnv)
    obs, _ = envs.reset(seed=0)
    assert obs.shape == (3, 23)
    for _ in range(100):
        obs, reward, terminated, truncated, infos = envs.step(np.zeros((3, 4), np.float32))
        assert obs.shape == (3, 23) and reward.shape == (3,)
        if (terminated | truncated).any():
            assert infos["final_obs"].shape == (3, 23) and infos["_final_obs"].tolist() == (terminated | truncated).tolist()
            break
    else:
        pytest.fail("no episode ended")
    with pytest.raises(ValueError, match="action"):
        envs.step(np.zeros((2, 4), np.float32))


def test_observation_is_the_torchrl_stacks():
    from quadwind_trl.envs import make_scenarios
    from quadwind_trl.estimator import load_estimator
    from quadwind_trl.rl.envs import make_env

    kwargs = _short("horizontal")
    sc = make_scenarios(2, traj_id="figure8_h", altitude_m=20.0, wind_speed_ref_m_s=6.0, turb_intensity=0.1,
                        turb_seed=[1, 2], sensor_seed=[3, 4], start_step=-1)
    envs = qgym.QuadWindVectorEnv("horizontal", 2, **kwargs)
    estimator = load_estimator("horizontal")
    ref = make_env("horizontal", estimator, 2, **qgym.shipped_policy_inputs("horizontal", estimator), **kwargs)
    obs, _ = envs.reset(options={"scenario": sc})
    td = ref.reset(scenario=sc)
    np.testing.assert_array_equal(obs, td["observation"].numpy())
    action = np.full((2, 4), 0.3, np.float32)
    obs, *_ = envs.step(action)
    td["action"] = torch.as_tensor(action)
    td = ref.step(td)
    np.testing.assert_array_equal(obs, td["next", "observation"].numpy())


@pytest.mark.skipif(importlib.util.find_spec("stable_baselines3") is None,
                    reason="stable-baselines3 is not installed (pip install -e '.[sb3]' or '.[test]')")
def test_sb3_example_trains(tmp_path):
    # two updates of 64 decisions (the recipe's several updates in a short run), an episode ended
    # (its 10 s flights are 100 decisions): flying was most of this test, and more of it checks nothing more
    out = subprocess.run(
        [sys.executable, str(ROOT / "recipes" / "sb3_ppo.py"), "--total-timesteps", "128", "--n-steps", "64",
         "--out", str(tmp_path)],
        cwd=ROOT, capture_output=True, text=True, timeout=600, env={**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])},
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert "SB3 PPO: 128 decisions" in out.stdout and "over the last 1 episodes" in out.stdout
    assert (tmp_path / "model.zip").exists()


def test_gym_filters_the_wind_estimate_as_the_shipped_policy_was_trained():
    from quadwind_trl.manifest import CHECKPOINT_DIR
    from quadwind_trl.rl.envs import find_transform, policy_env_settings
    from quadwind_trl.rl.policy import load_policy
    from quadwind_trl.transforms import WindEstimate

    for regime in ("horizontal", "vertical"):
        env = qgym.QuadWindVectorEnv(regime, 1, **_short(regime))
        wind = find_transform(env.stack.env, WindEstimate)
        _, payload = load_policy(CHECKPOINT_DIR / f"policy_{regime}.pt")
        assert wind.ema_config.tau_s == policy_env_settings(payload["env_spec"], wind.estimator)["ema_tau_s"]
        # an explicit setting still wins
        env = qgym.QuadWindVectorEnv(regime, 1, **(_short(regime) | {"ema_tau_s": 0.0}))
        assert find_transform(env.stack.env, WindEstimate).ema_config.tau_s == 0.0
