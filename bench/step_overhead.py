"""Where the compiled env step's time goes: the compiled graph against the Python around it.

    python bench/step_overhead.py                    # N = 64 and 45, the RL stack's hold of 10
    python bench/step_overhead.py --sizes 4096 --steps 20

One ``QuadWindEnv(compile_step=True)`` per size (the trainer's: batch dimension symbolic, a hold
of ``--hold`` control steps per env step), each in its own process, warmed up (compiled, or loaded
from the compile cache), then ``--steps`` env steps of the zero action through
``step_and_maybe_reset``, in this process's CPU time (on a loaded machine steadier than wall time).
Nothing in the library is changed to be measured: the bench wraps, from outside,

* ``QuadWindEnv._step`` (the env step: the hold, the observation, the reward);
* ``CompiledControlStep.__call__`` (the hold's compiled control steps with the TensorDicts'
  flattening and rebuilding around them);
* the compiled function that ``control_step._compiled_function`` returns (dynamo's guards and
  AOTAutograd's runtime wrappers around inductor's code);
* inductor's compiled module (``CompiledFxGraph.__call__``: its kernel and the Python wrapper that
  allocates its buffers and checks its inputs' sizes).

and prints one parseable line per size: each layer's own share in ms per env step (the layer's
time less the one inside it), and the loop's total::

    step_overhead N=64 hold=10 steps=200 threads=1 ms_per_env_step=... inductor_module=...
        dynamo_aot=... step_wrapper=... env_step_rest=... outside_env_step=... compiled_calls_per_env_step=10
        load_1min=...
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from collections import defaultdict
from dataclasses import replace

import torch
from machine import load_1min, machine_line


def measure(n: int, hold: int, steps: int) -> dict:
    from torch._inductor.output_code import CompiledFxGraph

    from quadwind_trl.config import EnvConfig
    from quadwind_trl.envs import QuadWindEnv, ScenarioSampler
    from quadwind_trl.envs import control_step

    seconds: dict[str, float] = defaultdict(float)
    calls: dict[str, int] = defaultdict(int)
    timing = [False]

    def timed(part: str, inner):
        def wrapper(*args, **kwargs):
            if not timing[0]:
                return inner(*args, **kwargs)
            t0 = time.process_time()
            try:
                return inner(*args, **kwargs)
            finally:
                seconds[part] += time.process_time() - t0
                calls[part] += 1
        return wrapper

    compiled_function = control_step._compiled_function
    control_step._compiled_function = lambda dynamic: timed("compiled", compiled_function(dynamic))
    QuadWindEnv._step = timed("env_step", QuadWindEnv._step)
    control_step.CompiledControlStep.__call__ = timed("wrapper", control_step.CompiledControlStep.__call__)
    CompiledFxGraph.__call__ = timed("inductor", CompiledFxGraph.__call__)

    cfg = EnvConfig()
    cfg = replace(cfg, timing=replace(cfg.timing, hold_control_steps=hold))
    env = QuadWindEnv(cfg, batch_size=[n], compile_step=True, scenario_sampler=ScenarioSampler(start="pattern"))
    td = env.reset()

    def rollout(k: int):
        nonlocal td
        for _ in range(k):
            td["action"] = torch.zeros(n, 4)
            _, td = env.step_and_maybe_reset(td)

    rollout(3)  # compiled, or loaded from the compile cache
    timing[0] = True
    t0 = time.process_time()
    rollout(steps)
    total = time.process_time() - t0
    per_step = lambda s: round(1e3 * s / steps, 3)  # noqa: E731
    return {
        "ms_per_env_step": per_step(total),
        "inductor_module": per_step(seconds["inductor"]),
        "dynamo_aot": per_step(seconds["compiled"] - seconds["inductor"]),
        "step_wrapper": per_step(seconds["wrapper"] - seconds["compiled"]),
        "env_step_rest": per_step(seconds["env_step"] - seconds["wrapper"]),
        "outside_env_step": per_step(total - seconds["env_step"]),
        "compiled_calls_per_env_step": calls["compiled"] / steps,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 45], help="N (the trainer's 64, the validation sweep's 45)")
    parser.add_argument("--hold", type=int, default=10, help="control steps per env step (the RL stack holds 10)")
    parser.add_argument("--steps", type=int, default=200, help="timed env steps")
    parser.add_argument("--single", action="store_true", help="measure the first size in this process")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.single:
        fields = {"N": args.sizes[0], "hold": args.hold, "steps": args.steps, "threads": 1,
                  **measure(args.sizes[0], args.hold, args.steps), "load_1min": round(load_1min(), 2)}
        print("step_overhead " + " ".join(f"{k}={v}" for k, v in fields.items()), flush=True)
        return
    print(machine_line(threads=1), flush=True)
    for n in args.sizes:
        subprocess.run([sys.executable, __file__, "--single", "--sizes", str(n), "--hold", str(args.hold),
                        "--steps", str(args.steps)], check=True)


if __name__ == "__main__":
    main()
