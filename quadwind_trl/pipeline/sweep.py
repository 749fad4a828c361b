"""Recipe candidates x seeds as one stage graph: a PPO run per (candidate, seed), every run a stage
of its own (run at once by either executor, as Ray tasks across a cluster), and a last stage that
writes one row per candidate: its kept policies' validation results over the seeds
(docs/rl.md, "Choosing the training recipe"; only validation flights choose, never a test sweep).
"""
from __future__ import annotations

import json
import math
import statistics
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from ..manifest import write_json
from .stages import Stage

#: the candidates, as options of the regime's PPO recipe: each changes one thing against the
#: paper's PPO (its constant learning rate); docs/history.md says why each was tried
CANDIDATES: dict[str, tuple[str, ...]] = {
    "paper": ("--lr-schedule", "constant"),
    "lr-decay": ("--lr-schedule", "linear"),
    "reward-scaling": ("--lr-schedule", "constant", "--reward-scaling", "return_std"),
}
#: the manifest metrics each row summarises over the seeds (mean, min, max)
ROW_METRICS = ("validation_score", "rmse", "improvement_rmse_xy_pct", "improvement_rmse_z_pct", "win_rate", "crashed")


@dataclass(frozen=True)
class SweepRun:
    candidate: str
    seed: int
    out: Path  # the PPO run's directory

    @property
    def stage(self) -> str:
        return f"{self.candidate}-seed{self.seed}"


def sweep_runs(candidates: Sequence[str], seeds: Sequence[int], runs_dir: Path) -> list[SweepRun]:
    unknown = [c for c in candidates if c not in CANDIDATES]
    if unknown:
        raise ValueError(f"candidates {unknown}: allowed: {', '.join(CANDIDATES)}")
    if not seeds or len(set(seeds)) != len(seeds) or any(s < 0 for s in seeds):
        raise ValueError(f"seeds={list(seeds)}: allowed: distinct integers >= 0, at least one")
    return [SweepRun(c, s, runs_dir / f"{c}_seed{s}") for c in candidates for s in seeds]


def sweep_stages(runs: Sequence[SweepRun], ppo_recipe: str, options: Sequence[str], table: Path) -> list[Stage]:
    """A PPO stage per run (``ppo_recipe`` with the candidate's options, then ``options``: the same
    for every run), each resumable, and the ``table`` stage after them all (:func:`write_table`)."""
    stages = [Stage(r.stage, (ppo_recipe, "--seed", str(r.seed), "--out", str(r.out), *CANDIDATES[r.candidate], *options,
                              "--resume", "--no-progress"), r.out / "policy.pt", needs=()) for r in runs]
    return stages + [Stage("table", (), table, after=lambda: write_table(runs, table), rerun=True)]


def sweep_rows(runs: Sequence[SweepRun]) -> list[dict]:
    """One row per candidate (in ``runs``' order): the seeds, and each of :data:`ROW_METRICS` of the
    kept policies (their manifests' ``metrics``) as mean, min and max over the seeds."""
    rows: dict[str, dict] = {}
    for run in runs:
        metrics = json.loads((run.out / "policy.json").read_text())["metrics"]
        row = rows.setdefault(run.candidate, {"candidate": run.candidate, "options": list(CANDIDATES[run.candidate]),
                                              "seeds": [], "values": {m: [] for m in ROW_METRICS}})
        row["seeds"].append(run.seed)
        for m in ROW_METRICS:
            row["values"][m].append(float(metrics.get(m, math.nan)))
    for row in rows.values():
        row["summary"] = {m: {"mean": statistics.fmean(v), "min": min(v), "max": max(v)} for m, v in row["values"].items()}
    return list(rows.values())


def rows_markdown(rows: Sequence[dict]) -> str:
    head = "| candidate | options | seeds | validation score (m) | xy vs PD (%) | z vs PD (%) | wins | crashed |"
    lines = [head, "|" + "---|" * head.count(" | ") + "---|"]
    for row in rows:
        s = row["summary"]

        def cell(m: str, fmt: str) -> str:
            return f"{s[m]['mean']:{fmt}} ({s[m]['min']:{fmt}} to {s[m]['max']:{fmt}})"

        lines.append(f"| {row['candidate']} | `{' '.join(row['options'])}` | {', '.join(map(str, row['seeds']))} | "
                     f"{cell('validation_score', '.3f')} | {cell('improvement_rmse_xy_pct', '+.1f')} | "
                     f"{cell('improvement_rmse_z_pct', '+.1f')} | {cell('win_rate', '.2f')} | {cell('crashed', '.1f')} |")
    return "\n".join(lines) + "\n"


def write_table(runs: Sequence[SweepRun], table: Path) -> None:
    """``table`` (JSON: the rows with every seed's values) and beside it the same rows as Markdown
    (mean, and the range over the seeds in brackets)."""
    rows = sweep_rows(runs)
    table.with_suffix(".md").write_text(rows_markdown(rows))
    write_json(table, {"rows": rows, "runs": [{"candidate": r.candidate, "seed": r.seed, "out": r.out.name} for r in runs]})
