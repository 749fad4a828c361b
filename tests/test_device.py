"""The same env and PPO on CUDA, unchanged but for ``device=``. Skipped only when no GPU is present
(this project's CI machine has none: these tests run where a GPU is)."""
from __future__ import annotations

import pytest
import torch

from dataclasses import replace

from quadwind_trl.config import ControllerConfig, EnvConfig
from quadwind_trl.envs import QuadWindEnv, make_scenarios
from quadwind_trl.keys import BASE_WIND_KEY
from quadwind_trl.regimes import classical_controller
from quadwind_trl.rl.config import PPOConfig
from quadwind_trl.rl.trainer import PPOTrainer

from conftest import short_trajectories
from test_ppo import hover_spec

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")


def _flown(device: str, controller: str | None = None) -> torch.Tensor:
    """60 steps of two rows under a varying action; ``controller`` a classical base law by name (the
    feed-forward laws read a constant wind estimate), None the paper's PD."""
    cfg = EnvConfig(trajectories=short_trajectories())
    changes = classical_controller("horizontal", controller)[0] if controller else {}
    cfg = replace(cfg, controller=replace(ControllerConfig(), **changes))
    sc = make_scenarios(2, traj_id=[1, 7], altitude_m=25.0, wind_speed_ref_m_s=8.0, turb_intensity=0.2,
                        turb_seed=torch.tensor([3, 4]), sensor_seed=torch.tensor([5, 6]), start_step=-1, device=device)
    env = QuadWindEnv(cfg, batch_size=[2], device=device)
    td = env.reset(scenario=sc)
    positions = []
    for k in range(60):
        td["action"] = torch.full((2, 4), 0.2 * ((k % 5) - 2), device=device)
        if cfg.controller.needs_wind:
            td[BASE_WIND_KEY] = torch.tensor([[3.0, -5.0], [-2.0, 6.0]], device=device)
        td = env.step(td)["next"]
        assert td["truth", "pos"].device.type == torch.device(device).type
        positions.append(td["truth", "pos"].cpu())
    return torch.stack(positions, 1)


@pytest.mark.parametrize("controller", [None, "pid", "dob", "pid_ff"])
def test_env_flies_on_cuda_as_on_cpu(controller):
    # the same operations on another device: equal to float rounding (not bit for bit); the
    # classical laws' state (integral, observer filter) lives on the env's device too
    torch.testing.assert_close(_flown("cuda", controller), _flown("cpu", controller), rtol=1e-4, atol=1e-3)


def test_ppo_trains_on_cuda(tmp_path):
    from dataclasses import replace

    from quadwind_trl.rl.envs import DEFAULT_ESTIMATE_EVERY_S

    # the estimator at every tick, as the recipes run it (test_ppo.py's trainer tests query it once a second)
    spec = replace(hover_spec(duration_s=1.0), device="cuda", estimate_every_s=DEFAULT_ESTIMATE_EVERY_S)
    cfg = PPOConfig(total_frames=2 * 4 * 32, num_envs=4, steps_per_env=32, epochs=1, minibatch=64, hidden=(32, 32),
                    eval_every_frames=0)
    res = PPOTrainer(spec, cfg, tmp_path / "run", progress=False).train()
    assert res.frames == 256 and all(torch.isfinite(torch.tensor(h["reward_mean"])) for h in res.history)
    payload = torch.load(tmp_path / "run" / "policy.pt", weights_only=True, map_location="cpu")
    assert payload["env_spec"]["device"] == "cuda"
