"""What the compiled control step costs to start: the first step of a compiled env in a first
and a second process, and whether a new batch size recompiles.

    python bench/compile_time.py                    # N = 16 64 4096, in the cache as it is
    python bench/compile_time.py --fresh-cache      # the first process starts from an empty cache
    python bench/compile_time.py --dynamic          # compile_step="dynamic" (default: static sizes)

Each of ``--processes`` fresh interpreters (one after the other, sharing the compile cache:
``quadwind_trl.envs.control_step.compile_cache_dir``, or with ``--fresh-cache`` a new temporary
folder) builds one compiled env per ``--sizes`` entry, in that order, and times its first step
(tracing, compilation or a cache load, and one control step) and its second. One parseable line
per env::

    compile_time process=1 N=16 first_step_s=... second_step_ms=... compiled_frames=1 graphs=1
        fxgraph_cache_hit=0 fxgraph_cache_miss=1 cache_dir=... load_1min=...

``compiled_frames`` counts dynamo's compilations in the process so far: a size that adds none
reused the graph (with ``--dynamic`` the batch dimension is symbolic; with static sizes each
size is a graph of its own); ``fxgraph_cache_hit``/``miss`` are inductor's FX-graph cache
lookups so far (a hit loads compiled code instead of compiling C++).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import torch
from machine import load_1min, machine_line


def one_process(sizes: list[int], threads: int, dynamic: bool) -> list[dict]:
    """In this process: a compiled env per size, its first and second steps timed."""
    from torch._dynamo.utils import counters

    from quadwind_trl.config import EnvConfig
    from quadwind_trl.envs import QuadWindEnv, ScenarioSampler
    # inductor's own folder (what envs.control_step.compile_cache_dir reports), read here so that
    # the bench also times commits from before that function
    from torch._inductor.runtime.cache_dir_utils import cache_dir

    torch.set_num_threads(threads)
    rows = []
    for n in sizes:
        env = QuadWindEnv(EnvConfig(), batch_size=[n], compile_step="dynamic" if dynamic else True,
                          scenario_sampler=ScenarioSampler(start="pattern"))
        td = env.reset()
        times = []
        for _ in range(2):
            td["action"] = torch.zeros(n, 4)
            start = time.perf_counter()
            td = env.step(td)["next"]
            times.append(time.perf_counter() - start)
        rows.append({"N": n, "first_step_s": round(times[0], 1), "second_step_ms": round(1e3 * times[1], 1),
                     "compiled_frames": counters["frames"]["ok"], "graphs": counters["stats"]["unique_graphs"],
                     "fxgraph_cache_hit": counters["inductor"]["fxgraph_cache_hit"],
                     "fxgraph_cache_miss": counters["inductor"]["fxgraph_cache_miss"],
                     "cache_dir": cache_dir(), "load_1min": round(load_1min(), 2)})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[16, 64, 4096])
    parser.add_argument("--processes", type=int, default=2)
    parser.add_argument("--fresh-cache", action="store_true", help="start the first process from an empty compile cache")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--dynamic", action="store_true", help='compile_step="dynamic": one graph for every batch size')
    parser.add_argument("--single", action="store_true", help="measure in this process, print one JSON list")
    args = parser.parse_args()
    if args.single:
        print(json.dumps(one_process(args.sizes, args.threads, args.dynamic)), flush=True)
        return
    print(machine_line(args.threads), flush=True)
    env = dict(os.environ)
    with tempfile.TemporaryDirectory(prefix="quadwind-compile-") as fresh:
        if args.fresh_cache:
            env["TORCHINDUCTOR_CACHE_DIR"] = fresh
        for process in range(1, args.processes + 1):
            run = subprocess.run([sys.executable, __file__, "--single", "--threads", str(args.threads),
                                  *(["--dynamic"] if args.dynamic else []), "--sizes", *map(str, args.sizes)],
                                 env=env, capture_output=True, text=True, check=True)
            for row in json.loads(run.stdout.strip().splitlines()[-1]):
                row = {"process": process, "mode": "dynamic" if args.dynamic else "static", **row}
                print("compile_time " + " ".join(f"{k}={v}" for k, v in row.items()), flush=True)


if __name__ == "__main__":
    main()
