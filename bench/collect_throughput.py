"""Environment steps per second during PPO collection with the wind-estimator transform on, and
where the time goes: simulation, estimator (network; and features + ring + EMA), the rest of the
collection (transforms, policy, collector), and the PPO update on the collected batch.

    python bench/collect_throughput.py                          # N = 256, 1024, 4096, 1 thread
    python bench/collect_throughput.py --sizes 64 --threads 2

Setup: the horizontal training env (``make_env``: ground starts, first-episode de-synchronisation,
the full transform stack, the compiled simulator step unless ``--eager``; one warm-up batch pays
the compilation), the TanhNormal 2x256 actor in RANDOM mode, TorchRL ``Collector``; the
estimator is the shipped one if present, else an untrained one of the same architecture (same cost).
Each size runs one warm-up batch, then ``--batches`` timed batches of ``N x --steps`` frames
(``--steps`` a multiple of 10, so every row ticks the estimator equally often), each followed, as in
training, by its PPO update (GAE + 10 epochs of 512-sample minibatches), every update timed.

One parseable line per size:
``collect_throughput N=... steps=... threads=... env_steps_per_s=... collect_s=... sim_s=...
estimator_net_s=... estimator_all_s=... other_s=... update_s=... update_frames_per_s=...
share_sim=... share_estimator=... share_other=... share_update=...`` (shares of collect + update).
"""
from __future__ import annotations

import argparse
import time

import torch
from machine import load_1min, machine_line


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def measure(n: int, steps: int, batches: int, estimator_path: str | None, compile_step: bool, device: str) -> dict:
    from torchrl.collectors import Collector
    from torchrl.envs.utils import ExplorationType

    from quadwind_trl.estimator import default_estimator_path, load_estimator
    from quadwind_trl.rl.config import PPOConfig
    from quadwind_trl.rl.envs import RLEnvSpec, make_env, wind_estimate
    from quadwind_trl.rl.policy import build_actor_critic
    from quadwind_trl.rl.trainer import episode_steps_hint
    from quadwind_trl.rl.update import PPOUpdate

    torch.manual_seed(0)
    path = estimator_path or (str(default_estimator_path("horizontal")) if default_estimator_path("horizontal").exists() else None)
    bundle = load_estimator("horizontal", path, untrained=path is None, device=device)
    env = make_env("horizontal", bundle, n, desync_steps=episode_steps_hint(RLEnvSpec("horizontal")),
                   compile_step=compile_step, device=device)
    dev = torch.device(device)
    base = env.base_env
    sim_time = [0.0]
    raw_step = base._hold  # an env step's held control steps (simulator + task + merge)

    def timed_step(*args, **kwargs):
        _sync(dev)
        t0 = time.perf_counter()
        out = raw_step(*args, **kwargs)
        _sync(dev)
        sim_time[0] += time.perf_counter() - t0
        return out

    base._hold = timed_step
    west = wind_estimate(env)
    tick_time = [0.0]
    raw_tick = west._tick

    def timed_tick(record, mask):
        _sync(dev)
        t0 = time.perf_counter()
        raw_tick(record, mask)
        _sync(dev)
        tick_time[0] += time.perf_counter() - t0

    west._tick = timed_tick
    cfg = PPOConfig()
    actor, value = build_actor_critic(cfg)
    actor, value = actor.to(dev), value.to(dev)
    collector = Collector(env, actor, frames_per_batch=n * steps, total_frames=n * steps * (batches + 1),
                          exploration_type=ExplorationType.RANDOM, auto_register_policy_transforms=False)
    learner = PPOUpdate(actor, value, cfg)  # the trainer's update: GAE + epochs of minibatch ClipPPO steps
    shuffle = torch.Generator().manual_seed(0)

    it = iter(collector)
    next(it)  # warm-up
    sim_time[0] = tick_time[0] = 0.0
    west.estimator_seconds = 0.0
    # as in training: collect a batch, update on it (the collector's policy is the updated actor),
    # every batch timed
    collect_s = update_total = 0.0
    for _ in range(batches):
        t0 = time.perf_counter()
        data = next(it)
        t1 = time.perf_counter()
        learner.update(data, shuffle)
        collect_s, update_total = collect_s + t1 - t0, update_total + time.perf_counter() - t1
    sim_s, est_all_s, est_net_s = sim_time[0], tick_time[0], west.estimator_seconds
    collector.shutdown()
    frames = n * steps * batches
    total = collect_s + update_total
    other_s = collect_s - sim_s - est_all_s
    return {
        "N": n,
        "steps": steps,
        "compile": compile_step,
        "device": device,
        "threads": torch.get_num_threads(),
        "env_steps_per_s": round(frames / collect_s),
        "collect_s": round(collect_s, 2),
        "sim_s": round(sim_s, 2),
        "estimator_net_s": round(est_net_s, 2),
        "estimator_all_s": round(est_all_s, 2),
        "other_s": round(other_s, 2),
        "update_s": round(update_total, 2),
        "update_frames_per_s": round(frames / update_total),
        "share_sim": round(sim_s / total, 3),
        "share_estimator": round(est_all_s / total, 3),
        "share_other": round(other_s / total, 3),
        "share_update": round(update_total / total, 3),
        "estimator": "shipped" if path else "untrained(same-architecture)",
        "load_1min": round(load_1min(), 2),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[256, 1024, 4096])
    parser.add_argument("--steps", type=int, default=20, help="steps per env per batch (multiple of 10)")
    parser.add_argument("--batches", type=int, default=2, help="timed batches per size")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--estimator", default=None, help="estimator checkpoint (default: shipped, else untrained)")
    parser.add_argument("--eager", action="store_true", help="the eager simulator step (default: compiled, as the RL stack)")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    if args.steps % 10:
        parser.error("--steps must be a multiple of 10 (the estimator ticks every 10 control steps)")
    torch.set_num_threads(args.threads)
    print(machine_line(args.threads), flush=True)
    for n in args.sizes:
        r = measure(n, args.steps, args.batches, args.estimator, not args.eager, args.device)
        print("collect_throughput " + " ".join(f"{k}={v}" for k, v in r.items()), flush=True)


if __name__ == "__main__":
    main()
