"""The headroom over the best classical base controller on each regime's test sweep: its error
split into the navigation error no controller can see, its tracking error in still air on the
true state, and what the wind adds (``quadwind_trl/studies/headroom.py``).

    python recipes/headroom.py                                  # both regimes: 6 flights of the sweep each
    python recipes/headroom.py --regimes vertical --winds full still
    python recipes/headroom.py --quick                          # smoke: small subset, short flights

The episodes are the paired ablation's: the regime's test sweep in the env the shipped policy
trained in (its config and simulator step), the base law with its chosen constants
(``regimes.CLASSICAL_CHOICES``). Writes ``results/headroom_<regime>.json`` (``--quick``: under
``runs/quick/results``) with the command, commit and platform, and prints a summary.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

from quadwind_trl.estimator import load_estimator
from quadwind_trl.studies.error_budget import WINDS
from quadwind_trl.evaluation.tracking import sweep_setup
from quadwind_trl.manifest import CHECKPOINT_DIR, command_line, git_commit, platform_info, repo_relative, write_json
from quadwind_trl.outputs import hold_for_command
from quadwind_trl.regimes import SWEEPS
from quadwind_trl.studies.headroom import BASE, BASES, headroom, summary_lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--regimes", nargs="+", default=["horizontal", "vertical"], choices=["horizontal", "vertical"])
    parser.add_argument("--base", default=BASE, choices=list(BASES), help="the classical base controller split")
    parser.add_argument("--winds", nargs="+", default=list(WINDS), choices=list(WINDS),
                        help="wind cells flown (full and still are needed; mean_only splits the wind into mean and turbulence)")
    parser.add_argument("--quick", action="store_true", help="one seed and intensity, 10 s patterns flown from their start")
    parser.add_argument("--results", type=Path, default=None, help="default results/ (--quick: runs/quick/results)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    results = args.results or Path("runs/quick/results" if args.quick else "results")
    outputs = [results / f"headroom_{regime}.json" for regime in args.regimes]
    hold_for_command(*outputs, what="headroom results", hint="wait for it to finish, or choose another --results")
    commit = git_commit()  # before this run writes its outputs: a second regime's file is not "dirty"
    for regime, out in zip(args.regimes, outputs):
        policy = CHECKPOINT_DIR / f"policy_{regime}.pt"
        scenarios, quick = sweep_setup(SWEEPS[regime], args.quick)
        start = time.perf_counter()
        result = headroom(regime, scenarios, policy, load_estimator(regime), args.base, quick,
                          winds=tuple(args.winds), progress=True)
        result.update(sweep=regime, command=command_line(sys.argv), git_commit=commit, platform=platform_info(),
                      policy=repo_relative(policy), quick=args.quick, wall_time_s=time.perf_counter() - start)
        write_json(out, result)
        for line in summary_lines(result):
            print(line)
        print(f"wrote {out} ({result['wall_time_s']:.0f} s)")


if __name__ == "__main__":
    main()
