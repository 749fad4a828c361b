"""The estimator experiments of issue 27, item 2, as a section of ``docs/results/`` that
``python recipes/report.py`` merges into docs/results.md.

    python recipes/estimator_experiments.py

Reads the training manifests of the experiment checkpoints (default: every
``results/experiments/estimator/*.pt`` with its JSON; made by ``recipes/train_estimator.py
--out results/experiments/estimator/NAME.pt`` and the experiment's flags), the shipped
checkpoint's manifest as the reference, and the ``recipes/evaluate_estimator.py`` JSONs named by
--evaluation (the shipped estimator's and those of the runs chosen on validation). Flies nothing.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

from quadwind_trl.estimator.training import load_estimator_data
from quadwind_trl.evaluation.estimation import trailing_mean_floor
from quadwind_trl.evaluation.estimation_experiments import experiments_markdown
from quadwind_trl.manifest import CHECKPOINT_DIR, command_line, git_commit, repo_relative

EXPERIMENTS = Path("results/experiments/estimator")
FLOOR_LENGTHS = (60, 100, 300, 600, 1200, 3000)  # samples: the window, the trailing means tried, the whole flight


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=Path, nargs="*", default=None, help="experiment checkpoints (default: every .pt in "
                        f"{EXPERIMENTS})")
    parser.add_argument("--evaluation", type=str, nargs="*", default=[], metavar="LABEL=JSON",
                        help="evaluate_estimator.py JSONs for the test table, each as label=path")
    parser.add_argument("--floor-data", type=Path, default=Path("data/flights_horizontal"),
                        help="dataset whose validation windows give the trailing-mean floors (skipped if absent)")
    parser.add_argument("--md", type=Path, default=Path("docs/results/4_estimator_experiments.md"))
    args = parser.parse_args()
    reference = json.loads((CHECKPOINT_DIR / "estimator_horizontal.json").read_text())
    paths = args.runs if args.runs is not None else sorted(EXPERIMENTS.glob("*.pt"))
    runs = []
    for path in paths:
        manifest = path.with_suffix(".json")
        if not manifest.exists():
            parser.error(f"--runs {path}: no training manifest {manifest} beside it")
        runs.append((repo_relative(path), json.loads(manifest.read_text())))
    evaluations = []
    for item in args.evaluation:
        label, sep, path = item.partition("=")
        if not sep or not Path(path).exists():
            parser.error(f"--evaluation {item!r}: expected LABEL=PATH of an existing evaluate_estimator.py JSON")
        evaluations.append((label, json.loads(Path(path).read_text()), repo_relative(Path(path))))
    floors = None
    if args.floor_data.exists():
        ed = load_estimator_data(args.floor_data, "horizontal", progress=False)
        wind = torch.as_tensor(ed.data["record", "wind"])[..., [1, 0]]  # ENU -> (north, east), as the labels
        val = ed.windows.tables["val"]
        floors = {  # the pattern begins at the crop, after the climb and its settling
            "the flight's start": trailing_mean_floor(wind, ed.windows.labels, val, FLOOR_LENGTHS),
            "the pattern's start": trailing_mean_floor(wind, ed.windows.labels, val, FLOOR_LENGTHS, first=ed.windows.crop),
        }
    md = [
        "## Estimator experiments on our field (issue 27)", "",
        f"Made by `{command_line(sys.argv)}` (commit `{git_commit()}`) from the checkpoints and evaluations listed below. "
        "Each run trains the shipped architecture and schedule on the shipped dataset "
        "(`data/flights_horizontal`, seed 1001) with one setting changed; runs are compared on the validation "
        "cases only, and only the shipped estimator and the runs chosen there were flown on the test cases.", "",
        experiments_markdown(reference, runs, evaluations, floors, ed.manifest["record_dt_s"] if floors else 0.1), "",
    ]  # fmt: skip
    args.md.parent.mkdir(parents=True, exist_ok=True)
    args.md.write_text("\n".join(md))
    print(f"wrote {args.md}: {len(runs)} runs, {len(evaluations)} evaluations")


if __name__ == "__main__":
    main()
