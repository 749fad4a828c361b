"""The wind estimators on both turbulence fields: the 2x2 of the network trained on
{our field, the paper's cube} x evaluated on {ours, cube}, with the model-based UKF on both, in
one section of ``docs/results/`` that ``python recipes/report.py`` merges into docs/results.md.

    python recipes/estimator_field.py

Reads the ``recipes/evaluate_estimator.py`` JSONs named by --evaluation (defaults: the committed
runs under results/experiments/cube/ and results/experiments/ukf/; missing ones are skipped with
a note) and flies nothing. Each row is labelled by its estimator: the UKF, or a network by the
turbulence layout of the dataset it was trained on (its checkpoint manifest's ``dataset``; a
checkpoint from before the layout was recorded trained on the default layout, the only one the
flight generator had then). The paper's figures sit beside the cube rows: ``paper_grid`` is the
layout that emulates the paper's field (docs/atmosphere.md).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from quadwind_trl.estimator.checkpoint import MODEL_BASED_ESTIMATORS
from quadwind_trl.evaluation.estimation_tables import field_comparison_markdown, turbulence_layout
from quadwind_trl.manifest import ROOT, command_line, git_commit, repo_relative

CUBE, UKF = Path("results/experiments/cube"), Path("results/experiments/ukf")
EVALUATIONS = [CUBE / f"{train}_on_{field}.json" for train in ("ours", "cube") for field in ("ours", "cube")]
EVALUATIONS += [UKF / "estimation_horizontal.json", UKF / "estimation_horizontal_paper_grid.json"]
PAPER_FIELD = "paper_grid"


def estimator_label(results: dict) -> str:
    checkpoint = results["checkpoint"]
    if checkpoint in MODEL_BASED_ESTIMATORS:
        return f"{checkpoint.upper()} (model-based, untrained)"
    manifest = json.loads((ROOT / checkpoint).with_suffix(".json").read_text())
    return f"network trained on `{turbulence_layout(manifest['dataset'])}`"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--evaluation", type=Path, nargs="+", default=EVALUATIONS, help="evaluate_estimator.py JSONs, one per row")
    parser.add_argument("--md", type=Path, default=Path("docs/results/3_estimator_field.md"))
    args = parser.parse_args()
    cells, missing = [], []
    for path in args.evaluation:
        if not path.exists():
            missing.append(repo_relative(path))
            continue
        results = json.loads(path.read_text())
        if results.get("regime") != "horizontal":
            parser.error(f"--evaluation {path}: regime {results.get('regime')!r}; the field comparison is horizontal")
        try:
            cells.append((estimator_label(results), results, repo_relative(path)))
        except (OSError, KeyError) as err:  # the checkpoint's manifest, or the evaluation's own fields
            parser.error(f"--evaluation {path}: cannot label its estimator ({type(err).__name__}: {err}); "
                         "expected an evaluate_estimator.py JSON whose checkpoint has its manifest beside it")
    if not cells:
        parser.error(f"--evaluation: none of {[repo_relative(p) for p in args.evaluation]} exists")
    md = ["## The estimator on the paper's turbulence field", "",
          f"Made by `{command_line(sys.argv)}` (commit `{git_commit()}`) from the evaluations listed at the end."
          + (f" Not yet evaluated: {', '.join(f'`{m}`' for m in missing)}." if missing else ""), "",
          field_comparison_markdown(cells, PAPER_FIELD)]  # fmt: skip
    args.md.parent.mkdir(parents=True, exist_ok=True)
    args.md.write_text("\n".join(md) + "\n")
    print(f"wrote {args.md} ({len(cells)} evaluations)")


if __name__ == "__main__":
    main()
