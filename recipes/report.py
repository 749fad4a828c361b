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
from quadwind_trl.studies.report import build_report
from quadwind_trl.studies.section import read_ablations
from quadwind_trl.studies.summary import page_summary_rows, results_summary
from quadwind_trl.studies.training import policy_runs
from quadwind_trl.outputs import hold_for_command

PREAMBLE = """# Results: ours beside the paper's

Every number here was produced by a recipe in this repository; each section names its command
and commit. Regenerate this page with `python recipes/report.py` after rerunning any stage
(`python recipes/reproduce.py` runs them all). Machine: 2 CPU cores, no GPU.

The RL policies are five seeds per regime of the recipes chosen on a validation sweep (three for
the trained oracle and the perception variants); the shipped policies, and the headline paired
ablation, are the median seeds by validation. How the designs and the calibration came to be what
they are is in [history.md](history.md).
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
    figure = None
    if read_ablations(args.results) and not args.toy:
        drawn = results_summary(page_summary_rows(args.results), args.out.parent / "figures" / "results_summary.png")
        figure = drawn.relative_to(args.out.parent).as_posix()
    text = build_report(args.results, args.sections, PREAMBLE, manifests, toy=args.toy, summary_figure=figure)
    tmp = args.out.with_name(args.out.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
