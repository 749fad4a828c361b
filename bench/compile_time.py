"""What the compiled control step costs to start: the first step of a compiled env in a first
and a second process, whether a new batch size recompiles, and whether the compile cache is
safe with two processes at once and with a corrupt entry.

    python bench/compile_time.py                        # N = 16 64 4096, in the cache as it is
    python bench/compile_time.py --fresh-cache          # the first process starts from an empty cache
    python bench/compile_time.py --mode static          # compile_step="static" (default: the library's, True)
    python bench/compile_time.py --fresh-cache --concurrent        # two processes at once on one empty cache
    python bench/compile_time.py --fresh-cache --corrupt entries   # truncate the cache's files between them

Each of ``--processes`` fresh interpreters (one after the other, or with ``--concurrent`` all at
once, sharing the compile cache: ``quadwind_trl.envs.compile_cache.compile_cache_dir``, or with
``--fresh-cache`` a new temporary folder) builds one compiled env per ``--sizes`` entry, in that
order, and times its first step (tracing, compilation or a cache load, and one control step) and
its second. One parseable line per env::

    compile_time process=1 mode=default N=16 first_step_s=... second_step_ms=... compiled_frames=1
        graphs=1 fxgraph_cache_hit=0 fxgraph_cache_miss=1 aot_cache_hit=0 aot_cache_miss=1
        dynamo_trace_s=... inductor_load_s=... state_sha=... cache_dir=... load_1min=...

``compiled_frames`` counts dynamo's compilations in the process so far: a size that adds none
reused the graph (with the default, the batch dimension is symbolic; with static sizes each size
is a graph of its own); ``fxgraph_cache_hit``/``miss`` are inductor's FX-graph cache lookups so
far (a hit loads compiled code instead of compiling C++), ``aot_cache_hit``/``miss`` the
AOTAutograd cache's; ``dynamo_trace_s`` is dynamo's tracing of the step's Python so far (every
process traces, cache or not) and ``inductor_load_s`` the loading of cached compiled code.
``state_sha`` is a hash of the env's state after its ``--steps`` steps (the same episodes and
actions in every process and mode): equal in every process, the same numbers were flown; equal
between ``--mode static`` and the default, the two compiled steps fly the same bits.
``--corrupt`` (with ``--fresh-cache``) truncates, after the first process, every file of one kind
in the cache to half its length (``entries``: the FX-graph and AOTAutograd caches' pickled
entries, ``kernels``: the compiled C++ libraries, ``all``); the line ``compile_cache_check`` then
says whether every later process flew the first one's numbers.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch
from machine import load_1min, machine_line

#: --mode: QuadWindEnv's compile_step
MODES = {"default": True, "static": "static", "dynamic": "dynamic"}
#: --corrupt: which of the cache's files are truncated (globs under the cache folder): the pickled
#: entries of inductor's FX-graph and AOTAutograd caches, the compiled C++ libraries, or every file
CORRUPTIBLE = {"entries": ("fxgraph/**/*", "aotautograd/**/*"), "kernels": ("**/*.so",), "all": ("**/*",)}


def one_process(sizes: list[int], threads: int, mode: str, steps: int) -> list[dict]:
    """In this process: a compiled env per size flown ``steps`` steps, its first and second timed."""
    from torch._dynamo.utils import compile_times, counters
    # inductor's own folder (where the library points it), read from torch so that the bench
    # also times commits from before the library chose the folder
    from torch._inductor.runtime.cache_dir_utils import cache_dir

    from quadwind_trl.config import EnvConfig
    from quadwind_trl.envs import QuadWindEnv, ScenarioSampler

    torch.set_num_threads(threads)
    rows = []
    for n in sizes:
        env = QuadWindEnv(EnvConfig(), batch_size=[n], compile_step=MODES[mode],
                          scenario_sampler=ScenarioSampler(start="pattern"))
        td = env.reset()
        times = []
        for k in range(steps):
            td["action"] = torch.full((n, 4), 0.1 * (k % 3))  # the base law and residuals of both signs' size
            start = time.perf_counter()
            td = env.step(td)["next"]
            times.append(time.perf_counter() - start)
        leaves = sorted(env.state.items(True, True), key=lambda kv: (kv[0],) if isinstance(kv[0], str) else kv[0])
        state = hashlib.sha256(b"".join(v.numpy().tobytes() for _, v in leaves))
        rows.append({"N": n, "first_step_s": round(times[0], 1), "second_step_ms": round(1e3 * times[1], 1),
                     "compiled_frames": counters["frames"]["ok"], "graphs": counters["stats"]["unique_graphs"],
                     "fxgraph_cache_hit": counters["inductor"]["fxgraph_cache_hit"],
                     "fxgraph_cache_miss": counters["inductor"]["fxgraph_cache_miss"],
                     "aot_cache_hit": counters["aot_autograd"]["autograd_cache_hit"],
                     "aot_cache_miss": counters["aot_autograd"]["autograd_cache_miss"],
                     "dynamo_trace_s": round(_compile_time(compile_times, "bytecode_tracing"), 1),
                     "inductor_load_s": round(_compile_time(compile_times, "AOTAutogradCache.inductor_load"), 1),
                     "state_sha": state.hexdigest()[:16], "cache_dir": cache_dir(), "load_1min": round(load_1min(), 2)})
    return rows


def _compile_time(compile_times, phase: str) -> float:
    """Seconds the process spent so far in one of dynamo's timed compile phases (0 if none)."""
    names, values = compile_times(repr="csv", aggregate=True)
    return float(values[names.index(phase)]) if phase in names else 0.0


def corrupt(folder: Path, kind: str) -> int:
    """Truncate every file of ``kind`` under ``folder`` to half its length, dated as a compile
    killed in an earlier session leaves them (older than the library's grace for a file being
    written, ``compile_cache.WRITE_GRACE_S``); how many were."""
    from quadwind_trl.envs.compile_cache import WRITE_GRACE_S

    files = [p for pattern in CORRUPTIBLE[kind] for p in folder.glob(pattern) if p.is_file() and p.stat().st_size > 1]
    then = time.time() - 2 * WRITE_GRACE_S
    for path in files:
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
        os.utime(path, (then, then))
    return len(files)


def _output(command: list[str], stdout: str, stderr: str, returncode: int) -> str:
    """A measuring process's output, or its error's end and an exit."""
    if returncode:
        raise SystemExit(f"{' '.join(command)} failed ({returncode}):\n{stderr[-3000:]}")
    return stdout


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[16, 64, 4096])
    parser.add_argument("--processes", type=int, default=2)
    parser.add_argument("--fresh-cache", action="store_true", help="start the first process from an empty compile cache")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--mode", choices=list(MODES), default="default",
                        help="the compiled step: the library's default (compile_step=True), static or dynamic sizes")
    parser.add_argument("--concurrent", action="store_true", help="start every process at once (one shared cache)")
    parser.add_argument("--corrupt", choices=list(CORRUPTIBLE), default=None,
                        help="after the first process, truncate the cache's files of this kind")
    parser.add_argument("--steps", type=int, default=2, help="env steps flown per env (at least 2; state_sha after the last)")
    parser.add_argument("--single", action="store_true", help="measure in this process, print one JSON list")
    args = parser.parse_args()
    if args.single:
        print(json.dumps(one_process(args.sizes, args.threads, args.mode, args.steps)), flush=True)
        return
    if args.steps < 2:
        parser.error(f"--steps={args.steps}; allowed: >= 2 (the first and the second step are timed)")
    if args.corrupt and (args.concurrent or not args.fresh_cache):
        parser.error("--corrupt truncates the cache between processes: with --fresh-cache (never the user's "
                     "cache), not with --concurrent")
    print(machine_line(args.threads), flush=True)
    env = dict(os.environ)
    command = [sys.executable, __file__, "--single", "--threads", str(args.threads), "--mode", args.mode,
               "--steps", str(args.steps), "--sizes", *map(str, args.sizes)]
    with tempfile.TemporaryDirectory(prefix="quadwind-compile-") as fresh:
        if args.fresh_cache:  # the library's variable; inductor's for commits from before it
            env["QUADWIND_TRL_COMPILE_CACHE"] = env["TORCHINDUCTOR_CACHE_DIR"] = fresh
        flown: list[str] = []

        def report(process: int, out: str) -> list[dict]:
            """Print one process's rows as they come (a later failure keeps them) and keep their hashes."""
            rows = json.loads(out.strip().splitlines()[-1])
            for row in rows:
                flown.append(row["state_sha"])
                print("compile_time " + " ".join(f"{k}={v}" for k, v in {"process": process, "mode": args.mode,
                                                                         **row}.items()), flush=True)
            return rows

        if args.concurrent:
            running = [subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                       for _ in range(args.processes)]
            for process, p in enumerate(running, 1):
                report(process, _output(p.args, *p.communicate(), p.returncode))
        else:
            for process in range(1, args.processes + 1):
                run = subprocess.run(command, env=env, capture_output=True, text=True)
                rows = report(process, _output(command, run.stdout, run.stderr, run.returncode))
                if process == 1 and args.corrupt:
                    folder = Path(rows[0]["cache_dir"])
                    print(f"compile_cache_corrupted kind={args.corrupt} files={corrupt(folder, args.corrupt)}", flush=True)
    n = len(args.sizes)
    same = all(flown[i] == flown[i % n] for i in range(len(flown)))
    print(f"compile_cache_check same_numbers_every_process={same}", flush=True)


if __name__ == "__main__":
    main()
