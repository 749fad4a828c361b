"""The paired ablation: PD, wind-blind RL, wind-aware RL and a true-wind oracle on identical
replayed episodes of the paper's evaluation sweeps; tables (JSON) and figures.

    python recipes/ablation.py                                   # horizontal 225, vertical 144, OOD 90
    python recipes/ablation.py --sweeps horizontal --policy runs/ppo_horizontal/policy.pt
    python recipes/ablation.py --quick                           # small subsets, short flights

By default the shipped checkpoints are used (``quadwind_trl/checkpoints/policy_<regime>.pt`` and
``estimator_<regime>.pt``). Writes ``results/ablation_<sweep>.json`` and ``docs/figures/*.png``
(``--quick``: under ``runs/quick/``); ``python recipes/report.py`` renders them into
docs/results.md.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

from quadwind_trl.evaluation import figures
from quadwind_trl.evaluation.ablation import CONTROLLERS, fly_controllers, policy_compile_step, summarize_ablation
from quadwind_trl.evaluation.tracking import sweep_setup
from quadwind_trl.manifest import command_line, git_commit, repo_relative, write_json
from quadwind_trl.estimator import load_estimator
from quadwind_trl.manifest import CHECKPOINT_DIR
from quadwind_trl.rl.policy import load_policy
from quadwind_trl.regimes import SWEEP_REGIME, SWEEPS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sweeps", nargs="+", default=list(SWEEPS), choices=list(SWEEPS))
    parser.add_argument("--policy", type=Path, nargs="*", default=None,
                        help="policy checkpoints, one per regime in the order horizontal, vertical (default: shipped)")
    parser.add_argument("--estimator", type=Path, nargs="*", default=None, help="estimator checkpoints, same order")
    parser.add_argument("--controllers", nargs="+", default=list(CONTROLLERS), choices=list(CONTROLLERS))
    parser.add_argument("--quick", action="store_true", help="one seed and intensity per sweep, 10 s patterns flown from their start")
    parser.add_argument("--results", type=Path, default=None, help="results directory (default results/, --quick runs/quick/results)")
    parser.add_argument("--figures", type=Path, default=None, help="figure directory (default docs/figures, --quick runs/quick/figures)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--eager", action="store_true",
                        help="fly the simulator eagerly (default: as the policy trained, compiled unless it recorded otherwise)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    results_dir = args.results or Path("runs/quick/results" if args.quick else "results")
    fig_dir = args.figures or Path("runs/quick/figures" if args.quick else "docs/figures")

    def checkpoint(kind: str, regime: str, given: list[Path] | None) -> Path:
        if given:
            return given[0 if regime == "horizontal" or len(given) == 1 else 1]
        return CHECKPOINT_DIR / f"{kind}_{regime}.pt"

    for name in args.sweeps:
        sweep, regime = SWEEPS[name], SWEEP_REGIME[name]
        policy_path = checkpoint("policy", regime, args.policy)
        estimator = load_estimator(regime, checkpoint("estimator", regime, args.estimator))
        scenarios, override = sweep_setup(sweep, args.quick)
        compile_step = False if args.eager else policy_compile_step(load_policy(policy_path)[1])
        start = time.perf_counter()
        results = fly_controllers(regime, scenarios, policy_path, estimator, tuple(args.controllers), progress=True,
                                  config_override=override, compile_step=compile_step)
        summary = summarize_ablation(sweep, scenarios, results)
        summary.update(command=command_line(sys.argv), git_commit=git_commit(), policy=repo_relative(policy_path),
                       estimator_manifest=estimator.manifest.get("metrics"), compile_step=compile_step, wall_time_s=time.perf_counter() - start)
        write_json(results_dir / f"ablation_{name}.json", summary)
        paths = figures.ablation_figures(name, scenarios, results, summary, fig_dir)
        aware = summary["rmse_xy"]["aware"]
        print(f"{name}: {summary['episodes']} episodes, {time.perf_counter() - start:.0f} s; wind-aware vs PD, xy RMSE reduction: "
              f"{aware['improvement']:.1f} % (95 % CI {aware['ci_low']:.1f}-{aware['ci_high']:.1f}), "
              f"wins {aware['wins']}/{aware['n']}; figures: {', '.join(str(p) for p in paths)}")


if __name__ == "__main__":
    main()
