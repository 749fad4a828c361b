"""Collection on Ray for one PPO run against the local collector, on the PPO training env: frames
per second, and where a batch's time goes. Each setting runs in a fresh process (as a user's run
does), with 1 torch thread per process.

    python bench/ray_collectors.py                                   # local, ray-1, ray-2; 64 rows x 32 steps
    python bench/ray_collectors.py --settings local workers-2 ray-1 ray-2 --batches 4
    python bench/ray_collectors.py --settings torchrl-ray-1 torchrl-ray-2   # TorchRL's RayCollector

Settings (the same frames per batch in all):

* ``local``: one TorchRL ``Collector`` in this process on the one-process env (``--collector local``).
* ``workers-K``: the rows in K local collection processes (``--collect-workers K``).
* ``ray-K``: the rows in K Ray actors of ``num_envs / K`` rows each (``--collector ray
  --num-collectors K``): a local Ray instance of K CPUs; the policy, the normalisation and the
  ``Collector`` in this process.
* ``torchrl-ray-K``: TorchRL's ``RayCollector(sync=True)`` with K remote ``Collector``\\ s of
  ``num_envs / K`` rows each, the weights sent before every batch as training would (each remote
  collector then normalises with statistics of its own rows: not the trainer's semantics; kept
  as the comparison docs/scaling.md draws).

Setup: ``rl.envs.build_env`` of the horizontal training spec (shipped estimator, EMA tau from its
manifest, estimator every tau / 30, de-synchronised first episodes, eager simulator), the
untrained PPO actor sampling actions. ``--batches`` are timed after one warm-up batch.

One parseable line per setting: ``collect setting=... frames_per_batch=... s_per_batch=...
frames_per_s=... startup_s=... driver_cpu_s=... wait_s=... rows_busy_s=... rows_cpu_s=...
estimator_s=... weight_sync_s=... load_1min=...``, the seconds per batch: ``driver_cpu_s`` the
CPU time of the process running the policy; ``wait_s`` its wall time waiting for the Ray actors;
``rows_busy_s`` the busiest actor's wall time resetting and stepping its rows (``wait_s`` minus
it: the transport and Ray's round trips); ``rows_cpu_s`` the CPU time of the processes holding
the rows (Ray actors: their rows and Ray's work for them; local workers), summed; ``estimator_s`` the wind estimator's, summed over the processes holding
rows. On a shared machine the CPU times say what a setting costs; the wall times also say how
much of the cores it got.
``startup_s``: Ray's start and the env's construction (every actor importing torch and building its rows).
"""
from __future__ import annotations

import argparse
import json
import os
import time

import torch
from machine import in_fresh_process, load_1min, machine_line


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
    return EnvFactory(spec, bundle=bundle), actor


def parse_setting(setting: str) -> tuple[str, int]:
    kind, _, k = setting.rpartition("-")
    if setting == "local":
        return "local", 1
    if kind not in ("workers", "ray", "torchrl-ray") or not k.isdigit() or int(k) < 1:
        raise ValueError(f"setting {setting!r}; allowed: local, workers-K, ray-K, torchrl-ray-K (K >= 1)")
    return kind, int(k)


def process_cpu_s(pid: int) -> float:
    """CPU seconds (user + system) of the process ``pid`` so far (Linux)."""
    fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime: fields 14, 15 of stat


class Counters:
    """Cumulative seconds of the parts of a batch, read before and after the timed batches."""

    def __init__(self, env=None):
        self.env = env

    def read(self) -> dict[str, float]:
        from torchrl.envs import ParallelEnv

        from quadwind_trl.envs import RayRowsEnv
        from quadwind_trl.rl.envs import estimator_seconds

        out = {"driver_cpu_s": time.process_time(), "wait_s": 0.0, "rows_busy_s": 0.0, "rows_cpu_s": 0.0,
               "estimator_s": 0.0}
        if self.env is None:  # a TorchRL RayCollector: its envs are remote
            return out
        out["estimator_s"] = estimator_seconds(self.env)
        rows = self.env.base_env
        if isinstance(rows, RayRowsEnv):
            usage = rows.usage()
            out["wait_s"], out["rows_busy_s"] = rows.wait_s, max(busy for busy, _ in usage)
            out["rows_cpu_s"] = sum(cpu for _, cpu in usage)
        elif isinstance(rows, ParallelEnv):  # local workers: their processes' CPU time, from Linux's account
            out["rows_cpu_s"] = sum(process_cpu_s(worker.pid) for worker in rows._workers)
        return out


def time_batches(collector, batches: int, counters: Counters, sync=lambda: None) -> dict[str, float]:
    """Seconds per batch, and of its parts (:class:`Counters`, ``weight_sync_s``), over
    ``batches`` after one warm-up batch."""
    it = iter(collector)
    next(it)
    before, sync_s, t0 = counters.read(), 0.0, time.perf_counter()
    for _ in range(batches):
        t = time.perf_counter()
        sync()
        sync_s += time.perf_counter() - t
        next(it)
    wall = time.perf_counter() - t0
    after = counters.read()
    return {"s_per_batch": wall / batches, **{k: (after[k] - before[k]) / batches for k in before},
            "weight_sync_s": sync_s / batches}


def measure(setting: str, num_envs: int, steps: int, batches: int) -> dict:
    """One setting, in this process."""
    from torchrl.collectors import Collector
    from torchrl.envs.utils import ExplorationType

    kind, k = parse_setting(setting)
    frames = num_envs * steps
    t0 = time.perf_counter()
    if kind in ("ray", "torchrl-ray"):
        import ray

        ray.init(num_cpus=k, include_dashboard=False, log_to_driver=False)
    try:
        if kind == "torchrl-ray":
            from torchrl.collectors.distributed import RayCollector

            factory, actor = build(num_envs // k)
            collector = RayCollector([factory] * k, policy=actor, frames_per_batch=frames, sync=True,
                                     total_frames=frames * (batches + 1),  # -1 would end it at once
                                     collector_class=Collector, exploration_type=ExplorationType.RANDOM,
                                     collector_kwargs={"auto_register_policy_transforms": False},
                                     remote_configs={"num_cpus": 1, "memory": 2 * 2**30},
                                     ray_init_config={"address": "auto"})
            counters, sync = Counters(), collector.update_policy_weights_
        else:
            factory, actor = build(num_envs)
            layout = {"local": {}, "workers": {"workers": k}, "ray": {"workers": k, "workers_on": "ray"}}[kind]
            env = factory(**layout)
            collector = Collector(env, actor, frames_per_batch=frames, total_frames=-1,
                                  exploration_type=ExplorationType.RANDOM, auto_register_policy_transforms=False)
            counters, sync = Counters(env), (lambda: None)
        startup = time.perf_counter() - t0
        try:
            parts = time_batches(collector, batches, counters, sync)
        finally:
            collector.shutdown()
    finally:
        if kind in ("ray", "torchrl-ray"):
            ray.shutdown()
    return {"setting": setting, "frames_per_batch": frames, "s_per_batch": parts["s_per_batch"],
            "frames_per_s": frames / parts["s_per_batch"], "startup_s": startup,
            **{key: value for key, value in parts.items() if key != "s_per_batch"}, "load_1min": load_1min()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--settings", nargs="+", default=["local", "ray-1", "ray-2"],
                        help="local, workers-K, ray-K, torchrl-ray-K (default: local ray-1 ray-2)")
    parser.add_argument("--num-envs", type=int, default=64)
    parser.add_argument("--steps", type=int, default=32, help="env steps per row per batch")
    parser.add_argument("--batches", type=int, default=4)
    parser.add_argument("--one", help=argparse.SUPPRESS)  # one setting in this process (internal)
    args = parser.parse_args()
    for setting in args.settings + ([args.one] if args.one else []):
        try:
            _, k = parse_setting(setting)
        except ValueError as err:
            parser.error(f"--settings: {err}")
        if args.num_envs % k:
            parser.error(f"--settings {setting}: K={k} must divide --num-envs={args.num_envs}")
    torch.set_num_threads(1)
    if args.one:
        print(json.dumps(measure(args.one, args.num_envs, args.steps, args.batches)))
        return
    workers = max(parse_setting(s)[1] for s in args.settings)
    print(machine_line(threads=1, workers=workers), flush=True)
    for setting in args.settings:
        in_fresh_process("collect", __file__, "--one", setting, "--num-envs", str(args.num_envs), "--steps", str(args.steps),
                         "--batches", str(args.batches))


if __name__ == "__main__":
    main()
