"""TorchRL's RayCollector on the PPO training env: frames per second with K Ray collectors against
the single-process Collector, and where a batch's time goes. It measures the building block a
``--collector ray`` would stand on; no PPO recipe collects this way yet (docs/scaling.md, "Collection
on Ray for one PPO run: not yet", says why: each collector would hold its own normalisation).

    python bench/ray_collectors.py                                 # 64 rows x 32 steps a batch; K = 1, 2
    python bench/ray_collectors.py --num-envs 256 --collectors 2 4 --batches 6

Setup: ``rl.envs.build_env`` of the horizontal training spec (shipped estimator, EMA tau from its
manifest, estimator every tau / 30, eager simulator), the untrained PPO actor sampling actions.
``local``: one ``Collector`` of ``--num-envs`` rows in this process. ``ray K``: a local Ray
instance of K CPUs and ``RayCollector(sync=True)`` with K remote ``Collector``s of ``num_envs / K``
rows each (the same frames per batch, split), the weights sent to them before every batch as
training would. ``--batches`` are timed after one warm-up batch. 1 torch thread per process.

One parseable line per setting: ``collect setting=... frames_per_batch=... s_per_batch=...
frames_per_s=... weight_sync_s=... startup_s=... load_1min=...``.
"""
from __future__ import annotations

import argparse
import time

import torch
from machine import load_1min, machine_line


def build(num_envs: int):
    from quadwind_trl.estimator import load_estimator
    from quadwind_trl.rl.config import PPOConfig
    from quadwind_trl.rl.envs import EnvFactory, RLEnvSpec, recipe_estimate_every_s, validated_tau_s
    from quadwind_trl.rl.policy import build_actor_critic

    bundle = load_estimator("horizontal")
    tau = validated_tau_s(bundle)
    spec = RLEnvSpec("horizontal", num_envs=num_envs, ema_tau_s=tau, compile_step=False,
                     estimate_every_s=recipe_estimate_every_s(tau, 0.1), desync_steps=200)
    torch.manual_seed(0)
    actor, _ = build_actor_critic(PPOConfig())
    return EnvFactory(spec), actor


def time_batches(collector, batches: int, sync) -> tuple[float, float]:
    """(seconds per batch, of which sending the weights), over ``batches`` after one warm-up."""
    it = iter(collector)
    next(it)
    sync_s, t0 = 0.0, time.perf_counter()
    for _ in range(batches):
        t = time.perf_counter()
        sync()
        sync_s += time.perf_counter() - t
        next(it)
    return (time.perf_counter() - t0) / batches, sync_s / batches


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--num-envs", type=int, default=64)
    parser.add_argument("--steps", type=int, default=32, help="env steps per row per batch")
    parser.add_argument("--collectors", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--batches", type=int, default=4)
    args = parser.parse_args()
    for k in args.collectors:
        if k < 1 or args.num_envs % k:
            parser.error(f"--collectors {k}: allowed: >= 1 and dividing --num-envs={args.num_envs}")
    torch.set_num_threads(1)
    from torchrl.collectors import Collector
    from torchrl.envs.utils import ExplorationType

    print(machine_line(threads=1, workers=max(args.collectors)), flush=True)
    frames = args.num_envs * args.steps
    t0 = time.perf_counter()
    factory, actor = build(args.num_envs)
    collector = Collector(factory(), actor, frames_per_batch=frames, total_frames=-1,
                          exploration_type=ExplorationType.RANDOM, auto_register_policy_transforms=False)
    startup = time.perf_counter() - t0
    per_batch, sync_s = time_batches(collector, args.batches, lambda: None)
    collector.shutdown()
    print(f"collect setting=local frames_per_batch={frames} s_per_batch={per_batch:.2f} frames_per_s={frames / per_batch:.0f} "
          f"weight_sync_s=0.00 startup_s={startup:.1f} load_1min={load_1min():.2f}", flush=True)

    import ray
    from torchrl.collectors.distributed import RayCollector

    for k in args.collectors:
        t0 = time.perf_counter()
        ray.init(num_cpus=k, include_dashboard=False, log_to_driver=False)
        factory, actor = build(args.num_envs // k)
        collector = RayCollector([factory] * k, policy=actor, frames_per_batch=frames, sync=True,
                                 total_frames=frames * (args.batches + 1),  # -1 would end it at once
                                 collector_class=Collector, exploration_type=ExplorationType.RANDOM,
                                 collector_kwargs={"auto_register_policy_transforms": False},
                                 remote_configs={"num_cpus": 1, "memory": 2 * 2**30},
                                 ray_init_config={"address": "auto"})
        startup = time.perf_counter() - t0
        per_batch, sync_s = time_batches(collector, args.batches, collector.update_policy_weights_)
        collector.shutdown()
        ray.shutdown()
        print(f"collect setting=ray_{k} frames_per_batch={frames} s_per_batch={per_batch:.2f} "
              f"frames_per_s={frames / per_batch:.0f} weight_sync_s={sync_s:.3f} startup_s={startup:.1f} "
              f"load_1min={load_1min():.2f}", flush=True)


if __name__ == "__main__":
    main()
