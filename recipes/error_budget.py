"""The PD baseline's error budget on an evaluation sweep: how much of the tracking error is
sensor bias no controller can remove, how much is white sensor noise, how much is wind, and what
the wind-aware policy removes under each sensing (``quadwind_trl/studies/error_budget.py``).

    python recipes/error_budget.py --sweep vertical            # 144 episodes x 9 PD + 3 policy flights
    python recipes/error_budget.py --sweep horizontal --sensors sbas --pd-only --winds full
    python recipes/error_budget.py --sweep vertical --quick    # smoke: small subset, short flights

The vehicle is the current default with the sensing preset ``--sensors`` (default ``rtk``);
``--sensors policy`` flies the policy's own saved vehicle instead (for a policy trained on an
earlier calibration, e.g. ``legacy_walk``; the first calibration's budgets are in git history, ``cdd87a3:results/legacy/``). ``--pd-only`` skips the policy flights. Uses the
shipped policy and estimator of the sweep's regime unless ``--policy``/``--estimator`` are given.
Writes ``results/error_budget_<sweep>[_<preset>].json`` (``--quick``: under ``runs/quick/``);
the stationary navigation error of the regime is the ``navigation``/``full`` cell's nav error.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

from quadwind_trl.config import SENSING, SENSOR_PRESETS, EnvConfig, with_sensor_preset
from quadwind_trl.evaluation.tracking import sweep_setup
from quadwind_trl.manifest import command_line, git_commit, platform_info, repo_relative, write_json
from quadwind_trl.estimator import load_estimator
from quadwind_trl.manifest import CHECKPOINT_DIR
from quadwind_trl.outputs import hold_for_command
from quadwind_trl.regimes import SWEEP_REGIME, SWEEPS
from quadwind_trl.studies.error_budget import WINDS, error_budget, on_vehicle, summary_lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sweep", default="vertical", choices=list(SWEEPS))
    parser.add_argument("--policy", type=Path, default=None, help="policy checkpoint (default: shipped)")
    parser.add_argument("--estimator", type=Path, default=None, help="estimator checkpoint (default: shipped)")
    parser.add_argument("--sensing", nargs="+", default=list(SENSING), choices=list(SENSING))
    parser.add_argument("--sensors", default="rtk", choices=[*SENSOR_PRESETS, "policy"],
                        help="sensing preset of the vehicle flown (policy: the policy's own saved vehicle)")
    parser.add_argument("--winds", nargs="+", default=list(WINDS), choices=list(WINDS))
    parser.add_argument("--pd-only", action="store_true", help="skip the wind-aware policy's flights")
    parser.add_argument("--quick", action="store_true", help="one seed and intensity, 10 s patterns flown from their start")
    parser.add_argument("--results", type=Path, default=None, help="default results/ (--quick: runs/quick/results)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    suffix = "" if args.sensors == "rtk" else f"_{args.sensors}"
    out = (args.results or Path("runs/quick/results" if args.quick else "results")) / f"error_budget_{args.sweep}{suffix}.json"
    hold_for_command(out, what="error budget", hint="wait for it to finish, or choose another --results")
    regime = SWEEP_REGIME[args.sweep]
    policy = args.policy or CHECKPOINT_DIR / f"policy_{regime}.pt"
    estimator = load_estimator(regime, args.estimator)
    scenarios, quick = sweep_setup(SWEEPS[args.sweep], args.quick)
    quick = quick or (lambda cfg: cfg)
    vehicle = None if args.sensors == "policy" else on_vehicle(with_sensor_preset(EnvConfig(), args.sensors))
    override = quick if vehicle is None else (lambda cfg: quick(vehicle(cfg)))
    start = time.perf_counter()
    budget = error_budget(regime, scenarios, policy, estimator, tuple(args.sensing), override, progress=True,
                          winds=tuple(args.winds), with_policy=not args.pd_only)
    budget.update(sweep=args.sweep, sensors=args.sensors, command=command_line(sys.argv), git_commit=git_commit(), platform=platform_info(),
                  policy=repo_relative(policy), wall_time_s=time.perf_counter() - start)
    write_json(out, budget)
    for line in summary_lines(budget, args.sweep, args.sensors):
        print(line)
    print(f"wrote {out} ({budget['wall_time_s']:.0f} s)")


if __name__ == "__main__":
    main()
