"""The PPO training env stepped in one process or in collection workers: env steps per second and
where the parent's time goes, at the batch sizes training uses.

    python bench/collect_workers.py                              # N = 64, 256, 1024; W = 1, 2
    python bench/collect_workers.py --sizes 256 --workers 1 2 --estimate-every-s 0.1

Setup: ``rl.envs.build_env`` of the horizontal training spec (the shipped estimator, EMA tau 30 s,
ground starts, de-synchronised first episodes, the compiled simulator step), ``workers`` =
``PPOConfig.collect_workers``; each setting in a fresh process (as a user's run is), 1 torch thread
per process. The action is zero (PD flies; a policy's forward pass on 64-1024 rows is small
beside a step); ``--warm-steps`` env steps pay the compilation, then ``--steps`` are timed.

One parseable line per setting: ``collect_workers N=... workers=... ms_per_env_step=...
frames_per_s=... estimator_ms=... parent_cpu_ms=... warm_s=... load_1min=...``. ``estimator_ms``
is the estimator's time per env step summed over the workers (they run at once);
``parent_cpu_ms`` is the CPU time of the process that runs the policy (with one worker: all of it).
"""
from __future__ import annotations

import argparse
import json
import time

import torch
from machine import in_fresh_process, load_1min, machine_line


def measure(n: int, workers: int, every_s: float, warm_steps: int, steps: int) -> dict:
    """One setting, in this process."""
    from quadwind_trl.estimator import load_estimator
    from quadwind_trl.rl.envs import RLEnvSpec, build_env, estimator_seconds, validated_tau_s

    bundle = load_estimator("horizontal")
    spec = RLEnvSpec("horizontal", num_envs=n, estimate_every_s=every_s, ema_tau_s=validated_tau_s(bundle),
                     desync_steps=200)
    env = build_env(spec, bundle, workers=workers)
    try:
        td = env.reset()

        def run(k: int) -> None:
            nonlocal td
            for _ in range(k):
                td["action"] = torch.zeros((*env.batch_size, 4))
                _, td = env.step_and_maybe_reset(td)

        t0 = time.perf_counter()
        run(warm_steps)
        warm = time.perf_counter() - t0
        est0, cpu0, t0 = estimator_seconds(env), time.process_time(), time.perf_counter()
        run(steps)
        wall = time.perf_counter() - t0
        return {"N": n, "workers": workers, "ms_per_env_step": 1e3 * wall / steps, "frames_per_s": n * steps / wall,
                "estimator_ms": 1e3 * (estimator_seconds(env) - est0) / steps,
                "parent_cpu_ms": 1e3 * (time.process_time() - cpu0) / steps, "warm_s": warm, "load_1min": load_1min()}
    finally:
        env.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 256, 1024])
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--estimate-every-s", type=float, default=1.0,
                        help="seconds between estimator queries (the PPO recipes' default at tau = 30 s: 1)")
    parser.add_argument("--warm-steps", type=int, default=20)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--one", nargs=2, type=int, help=argparse.SUPPRESS)  # N W: one setting in this process (internal)
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.one:
        print(json.dumps(measure(*args.one, args.estimate_every_s, args.warm_steps, args.steps)))
        return
    print(machine_line(threads=1, workers=max(args.workers)), flush=True)
    for n in args.sizes:
        for w in args.workers:
            in_fresh_process("collect_workers", __file__, "--one", str(n), str(w), "--estimate-every-s", str(args.estimate_every_s),
                             "--warm-steps", str(args.warm_steps), "--steps", str(args.steps))


if __name__ == "__main__":
    main()
