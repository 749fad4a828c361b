"""Control steps per second of ``QuadWindEnv.step`` (one control step = 5 physics steps + PD +
trajectory + wind + sensors), for several batch sizes, eager and compiled.

    python bench/env_throughput.py                       # the full table
    python bench/env_throughput.py --sizes 4096 --compile 1 --atmosphere full

Prints one parseable line per configuration:
``env_throughput N=4096 compile=True atmosphere=full control_steps_per_s=... peak_rss_mb=...``
"""
from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import time
from dataclasses import replace

import torch

from quadwind_trl.config import EnvConfig, SensorConfig, TurbulenceConfig
from quadwind_trl.envs import QuadWindEnv, ScenarioSampler


def make_config(atmosphere: str) -> EnvConfig:
    cfg = EnvConfig()
    if atmosphere == "mean":
        cfg = replace(cfg, turbulence=TurbulenceConfig(enabled=False), sensors=SensorConfig(enabled=False))
    return cfg


def measure(n: int, compile_step: bool, atmosphere: str, seconds: float, via: str) -> float:
    env = QuadWindEnv(
        make_config(atmosphere), batch_size=[n], compile_step=compile_step, scenario_sampler=ScenarioSampler(start="pattern")
    )
    td = env.reset()
    td["action"] = torch.zeros(n, 4)
    step = (lambda t: env.step(t)) if via == "step" else (lambda t: env.step_and_maybe_reset(t)[1])
    for _ in range(3):  # warm-up (and compilation)
        td = step(td)
        td["action"] = torch.zeros(n, 4)
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for _ in range(10):
            td = step(td)
            if via == "step":
                td = td["next"]
            td["action"] = torch.zeros(n, 4)
        steps += 10
    elapsed = time.perf_counter() - start
    return steps * n / elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 64, 1024, 4096, 16384])
    parser.add_argument("--compile", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--atmosphere", nargs="+", default=["mean", "full"], choices=["mean", "full"])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--threads", type=int, default=torch.get_num_threads())
    parser.add_argument("--via", default="step_and_maybe_reset", choices=["step", "step_and_maybe_reset"])
    parser.add_argument("--single", action="store_true", help="measure exactly one configuration in this process")
    args = parser.parse_args()
    if args.single:
        torch.set_num_threads(args.threads)
        n, compiled, atmosphere = args.sizes[0], bool(args.compile[0]), args.atmosphere[0]
        rate = measure(n, compiled, atmosphere, args.seconds, args.via)
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(
            f"env_throughput N={n} compile={compiled} atmosphere={atmosphere} "
            f"threads={args.threads} control_steps_per_s={rate:.0f} peak_rss_mb={peak:.0f}",
            flush=True,
        )
        return
    # one process per configuration, so each peak memory figure is its own
    for atmosphere in args.atmosphere:
        for compiled in args.compile:
            for n in args.sizes:
                subprocess.run(
                    [sys.executable, __file__, "--single", "--sizes", str(n), "--compile", str(compiled),
                     "--atmosphere", atmosphere, "--seconds", str(args.seconds), "--threads", str(args.threads),
                     "--via", args.via],
                    check=True,
                )


if __name__ == "__main__":
    main()
