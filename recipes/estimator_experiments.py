"""The estimator experiments as a section of ``docs/results/`` that
``python recipes/report.py`` merges into docs/results.md.

    python recipes/estimator_experiments.py

Reads the training manifests of the experiment checkpoints (default: every
``results/experiments/estimator/*.pt`` with its JSON; made by ``recipes/train_estimator.py
--out results/experiments/estimator/NAME.pt`` and the experiment's flags), the shipped
checkpoint's manifest of each run's regime as the reference, and the
``recipes/evaluate_estimator.py`` JSONs named by --evaluation (the shipped estimators' and those
of the runs chosen on validation). One part per regime that has runs or evaluations. Flies
nothing.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

from quadwind_trl.estimator.training import REGIMES, load_estimator_data
from quadwind_trl.evaluation.estimation import trailing_mean_floor
from quadwind_trl.manifest import CHECKPOINT_DIR, command_line, git_commit, repo_relative
from quadwind_trl.studies.estimation_experiments import experiments_markdown

EXPERIMENTS = Path("results/experiments/estimator")
FLOOR_LENGTHS = (60, 100, 300, 600, 1200, 3000)  # samples: the window, the trailing means tried, the whole flight


def regime_section(regime: str, runs: list, evaluations: list, floor_data: Path) -> str:
    """The section of one regime: its runs beside the shipped checkpoint, the averaged air of
    ``floor_data``'s validation windows (if that dataset is there), its test evaluations."""
    reference = json.loads((CHECKPOINT_DIR / f"estimator_{regime}.json").read_text())
    floors, dt_s = None, 0.1
    if floor_data.exists():
        ed = load_estimator_data(floor_data, regime, progress=False)
        wind = torch.as_tensor(ed.data["record", "wind"])[..., [1, 0]]  # ENU -> (north, east), as the labels
        val, dt_s = ed.windows.tables["val"], ed.manifest["record_dt_s"]
        floors = {"the flight's start": trailing_mean_floor(wind, ed.windows.labels, val, FLOOR_LENGTHS)}
        if bool((ed.windows.crop > 0).any()):  # windows begin at the crop (the horizontal pattern: after the climb)
            floors["the pattern's start"] = trailing_mean_floor(wind, ed.windows.labels, val, FLOOR_LENGTHS, first=ed.windows.crop)
    return experiments_markdown(reference, runs, evaluations, floors, dt_s)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=Path, nargs="*", default=None, help="experiment checkpoints (default: every .pt in "
                        f"{EXPERIMENTS})")
    parser.add_argument("--evaluation", type=str, nargs="*", default=[], metavar="LABEL=JSON",
                        help="evaluate_estimator.py JSONs for the test table, each as label=path")
    parser.add_argument("--data-dir", type=Path, default=Path("data"),
                        help="where flights_<regime> give the trailing-mean floors of their validation windows "
                             "(skipped if absent)")
    parser.add_argument("--md", type=Path, default=Path("docs/results/4_estimator_experiments.md"))
    args = parser.parse_args()
    paths = args.runs if args.runs is not None else sorted(EXPERIMENTS.glob("*.pt"))
    runs = {regime: [] for regime in REGIMES}
    for path in paths:
        manifest = path.with_suffix(".json")
        if not manifest.exists():
            parser.error(f"--runs {path}: no training manifest {manifest} beside it")
        m = json.loads(manifest.read_text())
        runs[m["config"]["regime"]].append((repo_relative(path), m))
    evaluations = {regime: [] for regime in REGIMES}
    for item in args.evaluation:
        label, sep, path = item.partition("=")
        if not sep or not Path(path).exists():
            parser.error(f"--evaluation {item!r}: expected LABEL=PATH of an existing evaluate_estimator.py JSON")
        r = json.loads(Path(path).read_text())
        evaluations[r["regime"]].append((label, r, repo_relative(Path(path))))
    md = [
        "## Estimator experiments on our field", "",
        f"Made by `{command_line(sys.argv)}` (commit `{git_commit()}`) from the checkpoints and evaluations listed below. "
        "Each run trains the shipped architecture and schedule of its regime on the shipped dataset "
        "(`data/flights_horizontal`, seed 1001; `data/flights_vertical`, seed 2001) with the settings named changed; runs "
        "are compared on the validation cases only, and only the shipped estimators and the runs chosen there were flown "
        "on the test cases.", "",
    ]  # fmt: skip
    for regime in REGIMES:
        if runs[regime] or evaluations[regime]:
            md += [regime_section(regime, runs[regime], evaluations[regime], args.data_dir / f"flights_{regime}"), ""]
    args.md.parent.mkdir(parents=True, exist_ok=True)
    args.md.write_text("\n".join(md))
    print(f"wrote {args.md}: {sum(map(len, runs.values()))} runs, {sum(map(len, evaluations.values()))} evaluations")


if __name__ == "__main__":
    main()
