"""The PD baseline's error budget on an evaluation sweep: how much of the tracking error is
sensor bias no controller can remove, how much is white sensor noise, how much is wind, and what
the wind-aware policy removes under each sensing (``quadwind_trl/evaluation/error_budget.py``).

    python recipes/error_budget.py --sweep vertical            # 144 episodes x 9 PD + 3 policy flights
    python recipes/error_budget.py --sweep horizontal
    python recipes/error_budget.py --sweep vertical --quick    # smoke: small subset, short flights

Uses the shipped policy and estimator of the sweep's regime unless ``--policy``/``--estimator``
are given. Writes ``results/error_budget_<sweep>.json`` (``--quick``: under ``runs/quick/``).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

from quadwind_trl.config import SENSING
from quadwind_trl.evaluation.error_budget import error_budget
from quadwind_trl.evaluation.tracking import sweep_setup
from quadwind_trl.manifest import command_line, git_commit, repo_relative, write_json
from quadwind_trl.modules.wind_estimator import CHECKPOINT_DIR
from quadwind_trl.rl.envs import load_estimator
from quadwind_trl.regimes import SWEEP_REGIME, SWEEPS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sweep", default="vertical", choices=list(SWEEPS))
    parser.add_argument("--policy", type=Path, default=None, help="policy checkpoint (default: shipped)")
    parser.add_argument("--estimator", type=Path, default=None, help="estimator checkpoint (default: shipped)")
    parser.add_argument("--sensing", nargs="+", default=list(SENSING), choices=list(SENSING))
    parser.add_argument("--quick", action="store_true", help="one seed and intensity, 10 s patterns flown from their start")
    parser.add_argument("--results", type=Path, default=None, help="default results/ (--quick: runs/quick/results)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    regime = SWEEP_REGIME[args.sweep]
    policy = args.policy or CHECKPOINT_DIR / f"policy_{regime}.pt"
    estimator = load_estimator(regime, args.estimator)
    scenarios, override = sweep_setup(SWEEPS[args.sweep], args.quick)
    start = time.perf_counter()
    budget = error_budget(regime, scenarios, policy, estimator, tuple(args.sensing), override, progress=True)
    budget.update(sweep=args.sweep, command=command_line(sys.argv), git_commit=git_commit(), policy=repo_relative(policy),
                  wall_time_s=time.perf_counter() - start)
    out = (args.results or Path("runs/quick/results" if args.quick else "results")) / f"error_budget_{args.sweep}.json"
    write_json(out, budget)
    for mode, cells in budget["pd"].items():
        aware = budget["aware_vs_pd"][mode]["rmse_xy"]
        print(f"{mode:>10}: PD xy full {cells['full']['rmse_xy']:.3f}, mean-only {cells['mean_only']['rmse_xy']:.3f}, "
              f"still {cells['still']['rmse_xy']:.3f} m, nav error {cells['full']['nav_rmse_xy']:.3f} m; "
              f"z full {cells['full']['rmse_z']:.3f} m; wind-aware vs PD, xy RMSE reduction "
              f"{aware['improvement']:.1f} % (wins {aware['wins']}/{aware['n']})")
    print(f"wrote {out} ({budget['wall_time_s']:.0f} s)")


if __name__ == "__main__":
    main()
