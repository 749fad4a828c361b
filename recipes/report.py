"""Build docs/results.md from the result files the recipes wrote.

    python recipes/report.py

Reads ``results/*.json`` (PD baseline, ...), every PPO run's manifest (``results/policies/``), the section files
in ``docs/results/`` (written by the estimator and ablation recipes), and the PPO runs' logs in
``runs/`` if present (learning curves), and writes ``docs/results.md`` with the paper's figures
beside ours.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from quadwind_trl.evaluation.figures import learning_curves
from quadwind_trl.evaluation.report import build_report, policy_runs
from quadwind_trl.outputs import hold_for_command

PREAMBLE = """# Results: ours beside the paper's

Every number here was produced by a recipe in this repository; each section names its command
and commit. Regenerate this page with `python recipes/report.py` after rerunning any stage
(`python recipes/reproduce.py` runs them all). Machine: 2 CPU cores, no GPU.

**The horizontal wind design changed at commit 4f617f5** (issue 25): the horizontal policy and
the horizontal and OOD sweeps now draw the shear exponent from the paper's RL range 0.08-0.15
instead of 0.15-0.25, which had put the strong-wind corner beyond the vehicle's flight envelope
([simulator.md](simulator.md#flight-envelope)). The RL policies are five seeds per regime of the
recipes chosen on the validation sweep (three for the trained oracle and the perception
variants); the shipped policies, and the headline paired ablation, are the median seeds by
validation.
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--results", type=Path, default=Path("results"))
    parser.add_argument("--sections", type=Path, default=Path("docs/results"))
    parser.add_argument("--out", type=Path, default=Path("docs/results.md"))
    parser.add_argument("--runs", type=Path, default=Path("runs"),
                        help="the PPO runs (RUNS/ppo_*): their manifests, else the kept ones in RESULTS/policies/, "
                             "and their logs, which redraw figures/learning_curves.png beside --out")
    parser.add_argument("--toy", action="store_true", help="the --quick run's page: says so first, no paper columns")
    args = parser.parse_args()
    # the page and its learning-curves figure beside it
    hold_for_command(args.out, what="report", hint="wait for it to finish, or choose another --out")
    manifests, runs = policy_runs(args.runs, args.results / "policies")
    if runs:
        learning_curves(runs, args.out.parent / "figures" / "learning_curves.png")
    text = build_report(args.results, args.sections, PREAMBLE, manifests, toy=args.toy)
    tmp = args.out.with_name(args.out.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
