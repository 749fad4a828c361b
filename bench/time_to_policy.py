"""Time to a good policy: wall time on this machine until a horizontal PPO run, started from the
shipped estimator, keeps a policy that beats PD by >= 40 % in xy RMSE on the validation sweep; and
what each training lever buys, as a ratio measured in the same invocation.

    python bench/time_to_policy.py                          # levers (~5 min), then the run
    python bench/time_to_policy.py --skip-levers --budget-s 1800 --eval-every 98304

Phase 1, the levers. Each setting trains ``--lever-batches`` batches after one warm-up batch
(which pays the simulator's compilation), each in a fresh process as a user's run is, one after
the other, and the bench prints the mean collection, estimator and update seconds per batch. The reference is the shipped
recipe (64 envs x 256 steps, estimator every 0.1 s, 10 epochs of 512-sample minibatches, 1
thread); each lever changes one thing:

* ``estimator 1 s``: the estimator queried every 1 s instead of 0.1 s (``--estimate-every-s``);
  its EMA keeps tau (what it changes in ``wind_hat`` and the ablation: ``bench/estimator_tick.py``);
* ``update 2 threads``: the update on both cores (collection stays single-threaded);
* ``minibatch 2048``: 8 minibatches per epoch instead of 32 (changes the optimisation, not only
  its cost: phase 2 says whether it learns as fast per frame);
* ``5 epochs``: half the passes over each batch (likewise);
* ``2 collection workers``: two single-threaded simulator processes, 32 rows each, with the
  estimator in them; the policy, the normalisation and the update stay in this process (the rows
  fly the same episodes: a speed change only);
* ``128 envs x 128 steps``, ``256 envs x 64 steps``: the same frames per batch in fewer, wider
  env steps (each step's fixed cost, the compiled step's launch, the estimator's tick and
  TorchRL's bookkeeping, is paid half or a quarter as often; the returns are bootstrapped from
  the value after 128 or 64 steps instead of 256: likewise a change to the optimisation).

Ratio = reference seconds per batch / lever seconds per batch (> 1: faster).

Phase 2, the run. PPO from scratch with ``--estimate-every-s``, ``--update-threads``, ``--minibatch``,
``--epochs``, ``--num-envs``, ``--steps-per-env`` and ``--collect-workers`` (defaults: the speed levers on, the paper's optimisation), evaluated on the whole
validation sweep (45 episodes) every ``--eval-every`` frames, by default in a second process
while training goes on on one thread (``--no-background-eval``: in the training process, which
then pauses for each; with ``--update-threads 2`` the update uses the core the evaluations need);
it stops at the first evaluation that reaches ``--target`` % xy improvement over PD (when its
result is in), or at ``--budget-s`` of wall time. One line per evaluation: frames, wall time
(training only and with evaluations; the same when they run beside training), xy improvement,
wins, validation score. The run directory is a scratch folder (``--out``); nothing is committed from it.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import torch
from machine import load_1min, machine_line

from quadwind_trl.estimator import load_estimator
from quadwind_trl.rl.config import PPOConfig
from quadwind_trl.rl.envs import RLEnvSpec, validated_tau_s
from quadwind_trl.rl.paired import validation_scenarios
from quadwind_trl.rl.trainer import PPOTrainer

REGIME = "horizontal"
LEVERS = {  # name -> (PPOConfig changes, RLEnvSpec changes)
    "reference": ({}, {}),
    "estimator 1 s": ({}, {"estimate_every_s": 1.0}),
    "update 2 threads": ({"update_threads": 2}, {}),
    "minibatch 2048": ({"minibatch": 2048}, {}),
    "5 epochs": ({"epochs": 5}, {}),
    "128 envs x 128 steps": ({"num_envs": 128, "steps_per_env": 128}, {}),
    "256 envs x 64 steps": ({"num_envs": 256, "steps_per_env": 64}, {}),
    "2 collection workers": ({"collect_workers": 2}, {}),
}


def reference_spec(seed: int) -> tuple[RLEnvSpec, object]:
    """The shipped recipe's env spec (the estimator's validated EMA tau) and the loaded estimator."""
    bundle = load_estimator(REGIME)
    return RLEnvSpec(REGIME, seed=seed, ema_tau_s=validated_tau_s(bundle)), bundle


def lever_batch_seconds(name: str, batches: int, seed: int) -> dict[str, float]:
    """Seconds per batch (collection, the estimator within it, update) of one lever setting, in
    this process (run it in a fresh one: see :func:`measure_levers`)."""
    spec, bundle = reference_spec(seed)
    cfg_changes, spec_changes = LEVERS[name]
    cfg = replace(PPOConfig(seed=seed, eval_every_frames=0, checkpoint_every_frames=10**12), **cfg_changes)
    cfg = replace(cfg, total_frames=(batches + 1) * cfg.frames_per_batch)
    with tempfile.TemporaryDirectory() as tmp:
        history = PPOTrainer(replace(spec, **spec_changes), cfg, Path(tmp) / "run", progress=False,
                             estimator_bundle=bundle).train().history
    timed = history[1:]  # the first batch warms up (and compiles the step)
    per = {k: sum(h[k] for h in timed) / len(timed) for k in ("collect_s", "update_s")}
    per["estimator_s"] = (history[-1]["estimator_s"] - history[0]["estimator_s"]) / len(timed)  # cumulative in the log
    per["batch_s"] = per["collect_s"] + per["update_s"]
    per["load_1min"] = load_1min()
    return per


def measure_levers(batches: int, seed: int, names: list[str]) -> dict[str, dict[str, float]]:
    """Each lever setting in a fresh process, as a user's training run is: in one process,
    torch.compile's cache of the simulator step fills up after a few envs and later envs step
    eagerly (measured here: collection 6x slower after the fifth run's evaluation)."""
    out = {}
    for name in ["reference"] + [n for n in names if n != "reference"]:
        proc = subprocess.run([sys.executable, __file__, "--lever", name, "--lever-batches", str(batches), "--seed", str(seed)],
                              capture_output=True, text=True, check=True)
        per = json.loads(proc.stdout.strip().splitlines()[-1])
        out[name] = per
        print(f"lever {name!r}: collect {per['collect_s']:.2f} s (estimator {per['estimator_s']:.2f} s), "
              f"update {per['update_s']:.2f} s, batch {per['batch_s']:.2f} s per {PPOConfig().frames_per_batch} frames; "
              f"load {per['load_1min']:.2f}", flush=True)
    ref = out["reference"]
    for name, per in out.items():
        print(f"ratio {name!r}: collect x{ref['collect_s'] / per['collect_s']:.2f}, update x{ref['update_s'] / per['update_s']:.2f}, "
              f"batch x{ref['batch_s'] / per['batch_s']:.2f}", flush=True)
    return out


def run_to_target(args: argparse.Namespace) -> list[dict]:
    """Phase 2: train until an evaluation reaches the target or the budget runs out; the curve."""
    spec, bundle = reference_spec(args.seed)
    spec = replace(spec, estimate_every_s=args.estimate_every_s)
    cfg = PPOConfig(seed=args.seed, total_frames=args.max_frames, eval_every_frames=args.eval_every,
                    checkpoint_every_frames=10**12, minibatch=args.minibatch, epochs=args.epochs,
                    update_threads=args.update_threads, num_envs=args.num_envs, steps_per_env=args.steps_per_env,
                    collect_workers=args.collect_workers, background_eval=args.background_eval)
    start = time.perf_counter()
    curve: list[dict] = []

    def stop_when(evals: list[dict]) -> bool:
        e = evals[-1]
        eval_total = sum(x["eval_s"] for x in evals)
        wall = time.perf_counter() - start
        # evaluations flown beside training (--background-eval) take no time out of it
        row = {"frames": e["frames"], "wall_s": wall, "eval_s": eval_total,
               "train_wall_s": wall if args.background_eval else wall - eval_total, "xy_pct": e["improvement_rmse_xy_pct"],
               "z_pct": e["improvement_rmse_z_pct"], "win_rate": e["win_rate"], "validation_score": e["validation_score"],
               "load_1min": load_1min()}
        curve.append(row)
        print("curve " + " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()), flush=True)
        return row["xy_pct"] >= args.target or row["wall_s"] >= args.budget_s

    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="time_to_policy_")) / "run"
    if out.exists():  # never delete a folder the user named: a run needs a fresh one
        raise SystemExit(f"error: --out {out} exists; choose a new folder")
    PPOTrainer(spec, cfg, out, eval_scenarios=validation_scenarios(REGIME), progress=False, estimator_bundle=bundle,
               stop_when=stop_when).train()
    reached = next((r for r in curve if r["xy_pct"] >= args.target), None)
    if reached:
        print(f"time_to_policy target={args.target:g}% reached frames={reached['frames']} wall_s={reached['wall_s']:.0f} "
              f"train_wall_s={reached['train_wall_s']:.0f}")
    else:
        best = max(curve, key=lambda r: r["xy_pct"])
        print(f"time_to_policy target={args.target:g}% not reached within {curve[-1]['wall_s']:.0f} s "
              f"({curve[-1]['frames']} frames); best xy {best['xy_pct']:.1f} % at {best['frames']} frames")
    (out / "curve.json").write_text(json.dumps(curve, indent=1))
    return curve


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--skip-levers", action="store_true")
    parser.add_argument("--lever-batches", type=int, default=3, help="timed batches per lever setting")
    parser.add_argument("--levers", nargs="+", choices=list(LEVERS), default=list(LEVERS),
                        help="the lever settings to measure (default: all; the reference always)")
    parser.add_argument("--skip-run", action="store_true")
    parser.add_argument("--lever", choices=list(LEVERS), help=argparse.SUPPRESS)  # one lever, in this process (internal)
    parser.add_argument("--target", type=float, default=40.0, help="xy RMSE improvement over PD on validation, %%")
    parser.add_argument("--budget-s", type=float, default=2400.0, help="wall-time limit of the run, s")
    parser.add_argument("--max-frames", type=int, default=1_500_000)
    parser.add_argument("--eval-every", type=int, default=131_072, help="frames between validation evaluations")
    parser.add_argument("--estimate-every-s", type=float, default=1.0)
    parser.add_argument("--update-threads", type=int, default=1)
    parser.add_argument("--minibatch", type=int, default=PPOConfig.minibatch)
    parser.add_argument("--epochs", type=int, default=PPOConfig.epochs)
    parser.add_argument("--num-envs", type=int, default=PPOConfig.num_envs)
    parser.add_argument("--steps-per-env", type=int, default=PPOConfig.steps_per_env)
    parser.add_argument("--collect-workers", type=int, default=PPOConfig.collect_workers)
    parser.add_argument("--background-eval", action=argparse.BooleanOptionalAction, default=True,
                        help="evaluate in a second process beside training (default; --no-background-eval: in this one)")
    parser.add_argument("--out", default=None, help="run directory (default: a new temporary folder)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.lever:
        print(json.dumps(lever_batch_seconds(args.lever, args.lever_batches, args.seed)))
        return
    print(machine_line(threads=1), flush=True)
    if not args.skip_levers:
        measure_levers(args.lever_batches, args.seed, args.levers)
    if not args.skip_run:
        run_to_target(args)


if __name__ == "__main__":
    main()
