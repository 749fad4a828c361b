"""A PPO run's rows stepped by Ray actors (``--collector ray``, ``rl/collection.py``): the batches
equal those of the same number of local collection workers bit for bit, a run trains, saves and
resumes on them and records where it collected, and a missing Ray or an unreachable ``--address``
is refused naming the options. Tiny batches on a local Ray instance of 2 CPUs."""
from __future__ import annotations

import json
import sys
from dataclasses import replace

import pytest
import torch
from tensordict import TensorDict

ray = pytest.importorskip("ray")

from quadwind_trl.ray_cluster import RayUnavailable  # noqa: E402
from quadwind_trl.rl.collection import check_ray  # noqa: E402
from quadwind_trl.rl.config import PPOConfig  # noqa: E402
from quadwind_trl.rl.envs import EnvFactory, estimator_seconds, set_trajectories  # noqa: E402
from quadwind_trl.rl.trainer import PPOTrainer  # noqa: E402
from test_ppo import BATCH, MINIBATCH, STEPS, hover_spec  # noqa: E402


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False)
    yield
    ray.shutdown()


def _collect(env, batches: int) -> torch.Tensor:
    """``batches`` batches of 4 rows x ``STEPS`` from a seeded untrained actor; after the first, a
    curriculum switch truncates every running episode (in each worker)."""
    from torchrl.collectors import Collector
    from torchrl.envs.utils import ExplorationType

    from quadwind_trl.rl.policy import build_actor_critic

    torch.manual_seed(0)
    actor, _ = build_actor_critic(PPOConfig(hidden=(32, 32)))
    collector = Collector(env, actor, frames_per_batch=BATCH, total_frames=-1, exploration_type=ExplorationType.RANDOM,
                          auto_register_policy_transforms=False)
    out = []
    try:
        for data in collector:
            out.append(data)
            if len(out) == 1:
                set_trajectories(env, ("hover",), truncate=True)
            if len(out) == batches:
                assert estimator_seconds(env) > 0
                break
    finally:
        collector.shutdown()
    return torch.cat(out, -1)


def test_ray_actors_collect_the_batches_of_local_workers_bit_for_bit(local_ray):
    """Two Ray actors of 2 rows each and two local workers of 2 rows each, with the normalisation,
    the policy and the collector in this process: every entry of two batches (observations,
    actions, log-probs, rewards, ends from the first-episode truncations and the curriculum
    switch) is the same, bit for bit."""
    spec = replace(hover_spec(duration_s=1.0), num_envs=4, desync_steps=6)
    factory = EnvFactory(spec)
    local = _collect(factory(workers=2), 2)
    env = factory(workers=2, workers_on="ray")
    assert len(env.base_env.nodes) == 2
    # refused by design (they would fly other rows than the local workers): a partial step, and a
    # seed of TorchRL's choosing instead of the makers' own
    with pytest.raises(NotImplementedError, match="partial step"):
        rows = env.base_env.batch_size
        env.base_env._step(TensorDict({"_step": torch.ones(*rows, 1, dtype=torch.bool)}, batch_size=rows))
    with pytest.raises(NotImplementedError, match="seed the rows through their constructors"):
        env.base_env.set_seed(0)
    remote = _collect(env, 2)
    assert remote.batch_size == local.batch_size == (2, 2, 2 * STEPS)
    assert int(local["next", "truncated"].sum()) >= 4 + 3  # the switch truncated every row, the desync some
    assert set(remote.keys(True, True)) == set(local.keys(True, True))
    differ = [key for key in local.keys(True, True) if not torch.equal(local[key], remote[key])]
    assert not differ, differ


def test_a_ppo_run_collecting_on_ray_trains_saves_resumes_and_records_it(local_ray, tmp_path):
    """A run of two Ray actors trains a batch, saves its policy and records the collector and K;
    resumed, on Ray again, it trains on. (It uses the Ray connection it finds and leaves it; the
    recipes' runs start a local instance of K CPUs and stop it.)"""
    spec = hover_spec(duration_s=1.0)
    cfg = PPOConfig(total_frames=BATCH, num_envs=4, steps_per_env=STEPS, epochs=1, minibatch=MINIBATCH, hidden=(32, 32),
                    eval_every_frames=0, checkpoint_every_frames=1, collector="ray", num_collectors=2)
    out = tmp_path / "run"
    res = PPOTrainer(spec, cfg, out, progress=False).train()
    assert res.frames == BATCH and (out / "policy.pt").exists() and ray.is_initialized()
    config = json.loads((out / "config.json").read_text())["ppo_config"]
    assert (config["collector"], config["num_collectors"]) == ("ray", 2)
    res = PPOTrainer(spec, replace(cfg, total_frames=2 * BATCH), out, progress=False).train(resume=True)
    assert res.frames == 2 * BATCH and res.iterations == 2 and len(res.history) == 1
    manifest = json.loads((out / "policy.json").read_text())
    assert (manifest["ppo_config"]["collector"], manifest["ppo_config"]["num_collectors"]) == ("ray", 2)
    assert manifest["collection"]["collector"] == "ray" and len(manifest["collection"]["nodes"]) == 2
    assert manifest["collection"]["rows_per_collector"] == 2


def test_a_missing_ray_or_an_unreachable_address_is_refused_naming_the_options(monkeypatch, capsys):
    cfg = PPOConfig(num_envs=4, steps_per_env=8, minibatch=16, collector="ray", num_collectors=2)
    with pytest.raises(RayUnavailable, match=r"--address 127.0.0.1:1: no Ray head node answers there"):
        check_ray(replace(cfg, ray_address="127.0.0.1:1"))
    # the recipes' command line: refused before anything is built
    from quadwind_trl.rl.cli import build_parser, run

    args = build_parser("horizontal", "").parse_args(["--quick", "--untrained-estimator", "--collector", "ray",
                                                      "--num-collectors", "2", "--address", "127.0.0.1:1"])
    threads = torch.get_num_threads()
    try:
        with pytest.raises(SystemExit, match=r"error: --address 127.0.0.1:1: no Ray head node answers there"):
            run("horizontal", args)
        args.address, args.num_collectors = None, 3
        with pytest.raises(SystemExit, match=r"num_collectors=3 \(--num-collectors\) must divide num_envs=8"):
            run("horizontal", args)
        args.num_collectors, args.device = 2, "cuda"
        with pytest.raises(SystemExit, match=r"--collector ray\) flies the rows on the CPU; got --device cuda"):
            run("horizontal", args)
    finally:
        torch.set_num_threads(threads)
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray fails as if not installed
    with pytest.raises(RayUnavailable, match=r"--collector ray needs Ray, which is not installed: pip install "
                                             r"'quadwind_trl\[ray\]', or leave out --collector ray, --num-collectors and "
                                             r"--address"):
        check_ray(cfg)
