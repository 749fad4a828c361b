"""Control steps per second of ``QuadWindEnv`` (one control step = 5 physics steps + PD +
trajectory + wind + sensors + navigation + reward for every row), and what a partial reset costs.

    python bench/env_throughput.py                       # the full table, 1 thread
    python bench/env_throughput.py --sizes 4096 --compile 1 --atmosphere full

Each configuration runs in its own process (so each peak-memory figure is its own) and prints one
parseable line::

    env_throughput N=4096 compile=True atmosphere=full sensors=True threads=1 workers=1 hold=1
        episode_s=200 resets_per_env_step=0.205 control_steps_per_s=... steady_control_steps_per_s=...
        steady_ms_per_control_step=... steady_cpu_ms_per_control_step=... aten_calls_per_control_step=...
        partial_reset_ms=... partial_reset_in_control_steps=... peak_rss_mb=... load_1min=...

``control_steps_per_s`` is what a user's rollout gets: steps through ``step_and_maybe_reset`` with
episodes ending at the rate a batch of de-synchronised ``--episode-s`` episodes has (``N /
(episode_s x 100 Hz)`` rows per control step; a bench run is far shorter than one episode, so rows
are ended by marking them done, cycling through the batch). ``steady_control_steps_per_s`` is the
same loop with no episode ending, ``steady_ms_per_control_step`` its time per control step of all
N rows, ``steady_cpu_ms_per_control_step`` the same in this process's CPU time (on a busy
machine the steadier figure: other processes lengthen the wall time, not this one's CPU time),
and ``aten_calls_per_control_step`` the ATen operators it calls per control step
(``torch.profiler``, outside the timed loops; one process only). ``partial_reset_ms`` is one
``env.reset`` of a single row (``"_reset"`` mask), ``partial_reset_in_control_steps`` the same in
control steps of the steady loop.
``--workers W`` splits the N rows over W single-threaded simulator processes
(:func:`quadwind_trl.envs.parallel.parallel_env`; ``peak_rss_mb`` is then the parent's alone);
``--hold K`` makes one env step K control steps, as the RL stack's decisions (K = 10); figures
are always per control step. ``--atmosphere mean`` switches the turbulence off; ``--sensors 0``
the sensor suite (the PD then flies the true state); neither changes anything else.

``--peer crazyflow`` adds, for every size, the same measurement of crazyflow 0.4 (JAX; as many XLA
threads as our largest configuration used cores, ``--threads`` x ``--workers``) in the same
run (``bench/peer_crazyflow.py``), in a virtual environment made on demand under
``.cache/peer-crazyflow`` (``pip install crazyflow==0.4.0``; a few minutes the first time).
"""
from __future__ import annotations

import argparse
import resource
from pathlib import Path
import subprocess
import sys
import time
from dataclasses import replace

import torch
from machine import load_1min, machine_line

from quadwind_trl.config import ControllerConfig, EnvConfig, SensorConfig, TurbulenceConfig
from quadwind_trl.envs import QuadWindEnv, ScenarioSampler
from quadwind_trl.envs.parallel import parallel_env

CONTROL_HZ = 100.0
PEER_VENV = Path(__file__).resolve().parent.parent / ".cache" / "peer-crazyflow"
PEER_REQUIREMENT = "crazyflow==0.4.0"


def peer_python() -> Path:
    """The peer's interpreter, installing crazyflow into its own venv on first use."""
    python = PEER_VENV / "bin" / "python"
    if not python.exists():
        print(f"installing {PEER_REQUIREMENT} into {PEER_VENV} (first use)", flush=True)
        subprocess.run([sys.executable, "-m", "venv", str(PEER_VENV)], check=True)
        subprocess.run([str(python), "-m", "pip", "install", "-q", PEER_REQUIREMENT], check=True)
    return python


def make_config(atmosphere: str, sensors: bool) -> EnvConfig:
    cfg = EnvConfig()
    if atmosphere == "mean":
        cfg = replace(cfg, turbulence=TurbulenceConfig(enabled=False))
    if not sensors:
        cfg = replace(cfg, sensors=SensorConfig(enabled=False), controller=replace(ControllerConfig(), feedback="truth"))
    return cfg


def _sync(device: torch.device) -> None:
    """Wait for the device's queued work (CUDA runs asynchronously), so a time is the work's."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _rollout(env, td, steps: int, resets_per_step: float) -> tuple[float, object]:
    """Seconds for ``steps`` env steps through ``step_and_maybe_reset``, ending rows at
    ``resets_per_step`` on average (a deterministic accumulator, one row at a time, cycling)."""
    n, dev = env.batch_size.numel(), env.device
    owed, row = 0.0, 0
    _sync(dev)
    start = time.perf_counter()
    for _ in range(steps):
        td["action"] = torch.zeros(*env.batch_size, 4, device=dev)
        owed += resets_per_step
        if owed >= 1.0:
            # rows whose episode ends on this step: marked done, then reset exactly as
            # step_and_maybe_reset does it (step, step_mdp, maybe_reset)
            k = int(owed)
            ending = torch.zeros(n, 1, dtype=torch.bool)
            ending[(row + torch.arange(k)) % n] = True
            ending = ending.reshape(*env.batch_size, 1).to(dev)
            owed, row = owed - k, (row + k) % n
            td = env._step_mdp(env.step(td))
            for key in ("done", "truncated"):
                td[key] = td[key] | ending
            td = env.maybe_reset(td)
        else:
            _, td = env.step_and_maybe_reset(td)
    _sync(dev)
    return time.perf_counter() - start, td


def aten_calls_per_control_step(env, td, steps: int = 5) -> tuple[float, object]:
    """ATen operator calls per control step of the steady loop, counted by ``torch.profiler``:
    the calls the Python code makes, not the ones an operator makes inside itself (``mul`` with
    a Python number counts once, not with its ``to``/``_to_copy``/``copy_``)."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU]) as prof:
        _, td = _rollout(env, td, steps, 0.0)
    top = [e for e in prof.events() if e.name.startswith("aten::")
           and (e.cpu_parent is None or not e.cpu_parent.name.startswith("aten::"))]
    return len(top) / (steps * env.config.timing.hold_control_steps), td


def measure(n: int, compile_step: bool | str, atmosphere: str, sensors: bool, seconds: float, episode_s: float,
            workers: int, hold: int, threads: int, device: str) -> dict:
    cfg = make_config(atmosphere, sensors)
    cfg = replace(cfg, timing=replace(cfg.timing, hold_control_steps=hold))
    sampler = ScenarioSampler(start="pattern")
    if workers == 1:
        env = QuadWindEnv(cfg, batch_size=[n], compile_step=compile_step, scenario_sampler=sampler, device=device)
    else:
        env = parallel_env(workers, n, cfg, threads_per_worker=threads, compile_step=compile_step,
                           scenario_sampler=sampler, device=device)
    td = env.reset()
    resets_per_step = n * hold / (episode_s * CONTROL_HZ)  # rows ending per env step
    _, td = _rollout(env, td, 3, 0.0)  # warm-up (and compilation)
    # steady: no episode ends
    steps, elapsed, cpu_start = 0, 0.0, time.process_time()
    while elapsed < seconds:
        dt, td = _rollout(env, td, 10, 0.0)
        elapsed, steps = elapsed + dt, steps + 10
    steady = steps * hold * n / elapsed
    steady_cpu_s = (time.process_time() - cpu_start) / (steps * hold)
    aten_calls, td = aten_calls_per_control_step(env, td) if workers == 1 else (None, td)
    # one partial reset of a single row, as step_and_maybe_reset issues it
    reset_times = []
    for i in range(5):
        mask = torch.zeros(n, dtype=torch.bool)
        mask[i % n] = True
        mask = mask.reshape(*env.batch_size, 1).to(env.device)
        _sync(env.device)
        t0 = time.perf_counter()
        env.reset(td.empty().set("_reset", mask))
        _sync(env.device)
        reset_times.append(time.perf_counter() - t0)
    reset_s = sorted(reset_times)[len(reset_times) // 2]
    # what a rollout gets: episodes ending at the de-synchronised batch's rate
    steps, elapsed = 0, 0.0
    while elapsed < seconds:
        dt, td = _rollout(env, td, 10, resets_per_step)
        elapsed, steps = elapsed + dt, steps + 10
    if workers > 1:
        env.close()
    return {
        "resets_per_env_step": round(resets_per_step, 3),
        "control_steps_per_s": round(steps * hold * n / elapsed),
        "steady_control_steps_per_s": round(steady),
        "steady_ms_per_control_step": round(1e3 * n / steady, 3),  # all N rows
        "steady_cpu_ms_per_control_step": round(1e3 * steady_cpu_s, 3),
        "aten_calls_per_control_step": None if aten_calls is None else round(aten_calls),
        "partial_reset_ms": round(1e3 * reset_s, 2),
        "partial_reset_in_control_steps": round(reset_s / (n / steady), 2),
    }


# --compile's values -> QuadWindEnv(compile_step=...)
COMPILE_STEP: dict[str, bool | str] = {"0": False, "1": True, "static": "static"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=None, help="N (default: 1 64 1024 4096 16384; cuda: 65536)")
    parser.add_argument("--compile", nargs="+", default=["0", "1"], choices=list(COMPILE_STEP),
                        help="0: eager; 1: compiled with the batch dimension symbolic (the env's default); static: "
                             "compiled for this N alone (one compilation per batch size)")
    parser.add_argument("--atmosphere", nargs="+", default=["full", "mean"], choices=["mean", "full"])
    parser.add_argument("--sensors", type=int, default=1, choices=[0, 1])
    parser.add_argument("--seconds", type=float, default=5.0, help="timed seconds per loop")
    parser.add_argument("--episode-s", type=float, default=200.0,
                        help="mean episode length that sets the reset rate (horizontal flights: ~190-200 s)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (per worker with --workers > 1)")
    parser.add_argument("--workers", type=int, nargs="+", default=[1],
                        help="simulator processes (envs.parallel.parallel_env), N split evenly; 1: one QuadWindEnv in this process")
    parser.add_argument("--device", default="cpu",
                        help="torch device of the simulator; with cuda, --sizes defaults to 65536 (skipped without a GPU)")
    parser.add_argument("--hold", type=int, default=1,
                        help="control steps per env step (TimingConfig.hold_control_steps; the RL stack holds 10)")
    parser.add_argument("--peer", choices=["crazyflow"], default=None, help="also measure a peer simulator, same N")
    parser.add_argument("--single", action="store_true", help="measure exactly one configuration in this process")
    args = parser.parse_args()
    cuda = torch.device(args.device).type == "cuda"
    if cuda and not torch.cuda.is_available():
        print(f"env_throughput device={args.device} skipped: no CUDA device on this machine", flush=True)
        return
    if args.sizes is None:
        args.sizes = [65536] if cuda else [1, 64, 1024, 4096, 16384]
    if args.single:
        torch.set_num_threads(args.threads)
        n, compiled, atmosphere = args.sizes[0], COMPILE_STEP[args.compile[0]], args.atmosphere[0]
        workers = args.workers[0]
        r = measure(n, compiled, atmosphere, bool(args.sensors), args.seconds, args.episode_s, workers, args.hold,
                    args.threads, args.device)
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        fields = {"N": n, "compile": compiled, "atmosphere": atmosphere, "sensors": bool(args.sensors),
                  "threads": args.threads, "workers": workers, "hold": args.hold, "device": args.device, "episode_s": args.episode_s, **r,
                  "peak_rss_mb": round(peak), "load_1min": round(load_1min(), 2)}
        print("env_throughput " + " ".join(f"{k}={v}" for k, v in fields.items()), flush=True)
        return
    print(machine_line(args.threads, max(args.workers)), flush=True)
    for atmosphere in args.atmosphere:
        for compiled in args.compile:
            for workers in args.workers:
                for n in args.sizes:
                    subprocess.run(
                        [sys.executable, __file__, "--single", "--sizes", str(n), "--compile", str(compiled),
                         "--atmosphere", atmosphere, "--sensors", str(args.sensors), "--seconds", str(args.seconds),
                         "--episode-s", str(args.episode_s), "--threads", str(args.threads), "--workers", str(workers),
                         "--hold", str(args.hold), "--device", args.device],
                        check=True,
                    )
    if args.peer == "crazyflow":
        # the peer gets the cores our largest configuration used: XLA threads = threads x workers
        subprocess.run([str(peer_python()), str(Path(__file__).with_name("peer_crazyflow.py")), "--sizes",
                        *map(str, args.sizes), "--seconds", str(args.seconds),
                        "--threads", str(args.threads * max(args.workers))],
                       check=True)


if __name__ == "__main__":
    main()
