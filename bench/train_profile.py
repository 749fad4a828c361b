"""Where a paper-scale training run's wall time goes: the shipped horizontal recipe's trainer, timed
phase by phase.

    python bench/train_profile.py                                  # 262,144 frames, one evaluation
    python bench/train_profile.py --frames 1507328                 # the whole shipped budget
    python bench/train_profile.py --no-background-eval             # evaluations in this process

The run is the one ``recipes/ppo_horizontal.py`` trains (the same ``PPOConfig``, env spec,
estimator, EMA tau, estimator interval, validation sweep and evaluation schedule: one evaluation
every 262,144 frames, flown in a second process beside training as the recipe does), stopped at
``--frames``. Nothing in the library is changed to measure it: the bench wraps, in this process,

* the simulator (``QuadWindEnv._step`` and ``_reset``: the held control steps, compiled as the
  recipe flies them; the first batch pays their compilation);
* the wind estimator's network (the estimator's ``predict``: the 10 Hz ticks' windows);
* the policy's forward pass during collection (``ProbabilisticActor.forward``);
* the PPO update (``PPOUpdate.update``);
* the evaluations as the trainer waits for them (``PPOTrainer._evaluate`` and
  ``_receive_evaluations``: with background evaluations, the submission and the wait at the run's
  end; in-process, the whole evaluation, split into the same simulator, estimator and policy parts);
* checkpointing (``PPOTrainer._checkpoint``), the start (networks, envs, the evaluation process)
  and the finish (``policy.pt``).

"Collection, the rest" is the collector's time the three collection parts leave: the transforms
(episode control, the estimator's feature ring and EMA, the observation, the normalisation), the
TorchRL collector's bookkeeping. Each evaluation's own duration (``eval_s``, measured where it
flies; the first includes the eval env's compilation and PD's flights, unless an earlier run on
this machine and code kept them: ``rl/pd_flights.py``; the report says which) is printed too.
``QUADWIND_TRL_CACHE_DIR=$(mktemp -d)`` profiles a first run, which flies PD. One
table, each batch's collection and update seconds, then one parseable ``profile`` line per phase.
The run directory is a scratch folder.
"""
from __future__ import annotations

import argparse
import functools
import json
import sys
import tempfile
import time
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

import torch
from machine import load_1min, machine_line
from torchrl.modules import ProbabilisticActor

from quadwind_trl.envs.quad_env import QuadWindEnv
from quadwind_trl.estimator import load_estimator
from quadwind_trl.rl.cli import DEFAULT_BACKGROUND_EVAL, DEFAULT_EVAL_EVERY
from quadwind_trl.rl.config import PPOConfig
from quadwind_trl.rl.envs import RLEnvSpec, recipe_estimate_every_s, validated_tau_s
from quadwind_trl.rl.paired import validation_scenarios
from quadwind_trl.cache import cache_dir
from quadwind_trl.rl.pd_flights import entry_path
from quadwind_trl.rl.trainer import PPOTrainer
from quadwind_trl.rl.update import PPOUpdate

REGIME = "horizontal"


class PhaseTimer:
    """Seconds per (phase, part): a part's time is booked to the phase the trainer is in."""

    def __init__(self):
        self.phase = "start"
        self.seconds: dict[tuple[str, str], float] = defaultdict(float)
        self.calls: dict[tuple[str, str], int] = defaultdict(int)
        self._depth: dict[str, int] = defaultdict(int)

    def wrap(self, owner: type, name: str, part: str, phase: str | None = None) -> None:
        """Time ``owner.name`` as ``part``; with ``phase``, the trainer is in that phase meanwhile.
        Re-entrant calls (a part inside itself) are counted once."""
        inner = getattr(owner, name)

        @functools.wraps(inner)
        def timed(*args, **kwargs):
            before, outer = self.phase, self._depth[part] == 0
            if phase is not None:
                self.phase = phase
            self._depth[part] += 1
            t0 = time.perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                self._depth[part] -= 1
                if outer:
                    self.seconds[(self.phase, part)] += time.perf_counter() - t0
                    self.calls[(self.phase, part)] += 1
                self.phase = before

        setattr(owner, name, timed)


def recipe_setup(seed: int) -> tuple[RLEnvSpec, PPOConfig, object]:
    """What ``recipes/ppo_horizontal.py`` trains with its defaults (``rl/cli.py``'s ``run``)."""
    bundle = load_estimator(REGIME)
    tau_s = validated_tau_s(bundle)
    spec = RLEnvSpec(regime=REGIME, seed=seed, ema_tau_s=tau_s)
    spec = replace(spec, estimate_every_s=recipe_estimate_every_s(tau_s, spec.env_config.timing.log_dt_s))
    cfg = PPOConfig(seed=seed, threads=1, eval_every_frames=DEFAULT_EVAL_EVERY[REGIME], background_eval=DEFAULT_BACKGROUND_EVAL)
    return spec, cfg, bundle


def profile(frames: int, seed: int, background_eval: bool) -> dict:
    spec, cfg, bundle = recipe_setup(seed)
    cfg = replace(cfg, total_frames=frames, background_eval=background_eval).validate()
    timer = PhaseTimer()
    timer.wrap(QuadWindEnv, "_step", "simulator")
    timer.wrap(QuadWindEnv, "_reset", "simulator")
    timer.wrap(type(bundle), "predict", "estimator")
    timer.wrap(ProbabilisticActor, "forward", "policy")
    timer.wrap(PPOUpdate, "update", "update", phase="update")
    timer.wrap(PPOTrainer, "_evaluate", "evaluation", phase="evaluation")
    timer.wrap(PPOTrainer, "_receive_evaluations", "evaluation", phase="evaluation")
    timer.wrap(PPOTrainer, "_checkpoint", "checkpoint", phase="checkpoint")
    timer.wrap(PPOTrainer, "_start", "start", phase="start")
    timer.wrap(PPOTrainer, "_finish", "finish", phase="finish")
    history: list[dict] = []

    def on_iteration(metrics: dict) -> None:
        history.append(metrics)
        timer.phase = "collection"  # the collector's next batch

    scenarios = validation_scenarios(REGIME)
    with tempfile.TemporaryDirectory() as tmp:
        trainer = PPOTrainer(spec, cfg, Path(tmp) / "run", eval_scenarios=scenarios, progress=False,
                             estimator_bundle=bundle, on_iteration=on_iteration, command="bench/train_profile.py")
        pd_kept = entry_path(trainer.eval_spec, scenarios.batch_size[0], scenarios).exists()
        timer.phase = "collection"
        t0 = time.perf_counter()
        result = trainer.train()
        wall = time.perf_counter() - t0
    return {"wall_s": wall, "timer": timer, "history": history, "evals": result.evals, "frames": result.frames,
            "spec": spec, "cfg": cfg, "pd_kept": pd_kept}


def report(run: dict) -> None:
    timer, history, wall = run["timer"], run["history"], run["wall_s"]
    sec = timer.seconds
    collect = sum(h["collect_s"] for h in history)
    first = history[0]["collect_s"] if history else 0.0
    parts = {p: sec[("collection", p)] for p in ("simulator", "estimator", "policy")}
    rows = [
        ("collection (all batches)", collect),
        ("  simulator step (first batch compiles it)", parts["simulator"]),
        ("  estimator network (10 Hz ticks)", parts["estimator"]),
        ("  policy forward", parts["policy"]),
        ("  the rest (transforms, collector bookkeeping)", collect - sum(parts.values())),
        ("  of which the first batch", first),
        ("PPO update", sec[("update", "update")]),
        ("evaluation, as the trainer waits for it", sec[("evaluation", "evaluation")]),
    ]
    if not run["cfg"].background_eval:
        rows += [(f"  {p}", sec[("evaluation", p)]) for p in ("simulator", "estimator", "policy")]
    rows += [
        ("checkpointing", sec[("checkpoint", "checkpoint")]),
        ("start (networks, envs, evaluation process)", sec[("start", "start")]),
        ("finish (policy.pt)", sec[("finish", "finish")]),
    ]
    accounted = collect + sum(sec[(k, k)] for k in ("update", "evaluation", "checkpoint", "start", "finish"))
    rows.append(("other (logging, the trainer's loop)", wall - accounted))
    rows.append(("wall time of train()", wall))
    print(f"\nframes {run['frames']:,} in {len(history)} batches; evaluations {len(run['evals'])}; "
          f"background evaluation: {run['cfg'].background_eval}; load {load_1min():.2f}")
    print("PD's validation flights: " + ("kept by an earlier run, read from the cache" if run["pd_kept"] else
                                        f"flown by this run (none kept in {cache_dir() / 'pd_flights'})"))
    print(f"| phase | s | share of wall |\n|---|---|---|")
    for name, s in rows:
        print(f"| {name} | {s:.1f} | {100 * s / wall:.1f} % |")
    # per batch: whether a phase slowed down over the run (another process's share of the cores) or not
    print("per batch (collection / update, s): " + ", ".join(f"{h['collect_s']:.1f}/{h['update_s']:.1f}" for h in history))
    for e in run["evals"]:
        print(f"evaluation at {e['frames']:,} frames: {e['eval_s']:.1f} s of flying (its own process or this one), "
              f"xy vs PD {e['improvement_rmse_xy_pct']:+.2f} %, validation score {e['validation_score']:.4f} m")
    for name, s in rows:
        print("profile " + json.dumps({"phase": name.strip(), "s": round(s, 2)}))
    print("profile_evals " + json.dumps([{k: e[k] for k in ("frames", "eval_s", "validation_score", "improvement_rmse_xy_pct")}
                                         for e in run["evals"]]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=DEFAULT_EVAL_EVERY[REGIME],
                        help="frames to train (whole batches of 16,384); default: up to the first evaluation")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--background-eval", action=argparse.BooleanOptionalAction, default=DEFAULT_BACKGROUND_EVAL,
                        help="evaluate beside training, as the recipe does (default); --no-background-eval: in this process")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(machine_line(threads=1), flush=True)
    report(profile(args.frames, args.seed, args.background_eval))
    sys.stdout.flush()


if __name__ == "__main__":
    main()
