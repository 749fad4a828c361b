"""Recipe candidates x seeds as one stage graph (``recipes/recipe_sweep.py``): a resumable PPO
stage per run, the table after them all, one row per candidate over its seeds."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from quadwind_trl.pipeline import stage_needs
from quadwind_trl.pipeline.sweep import CANDIDATES, sweep_runs, sweep_stages, write_table

ROOT = Path(__file__).resolve().parent.parent


def test_every_run_is_a_stage_of_its_own_and_the_table_follows_them_all(tmp_path):
    runs = sweep_runs(["paper", "lr-decay"], [0, 1], tmp_path)
    plan = sweep_stages(runs, "ppo_horizontal.py", ("--quick",), tmp_path / "table.json")
    assert [s.name for s in plan] == ["paper-seed0", "paper-seed1", "lr-decay-seed0", "lr-decay-seed1", "table"]
    assert all(stage_needs(s, plan) == () for s in plan[:-1])  # the runs all at once
    assert stage_needs(plan[-1], plan) == tuple(s.name for s in plan[:-1]) and plan[-1].rerun
    args = plan[2].args
    assert args[:5] == ("ppo_horizontal.py", "--seed", "0", "--out", str(tmp_path / "lr-decay_seed0"))
    assert args[5:] == (*CANDIDATES["lr-decay"], "--quick", "--resume", "--no-progress")
    with pytest.raises(ValueError, match=r"candidates \['adam'\]: allowed: paper, lr-decay, reward-scaling"):
        sweep_runs(["adam"], [0], tmp_path)
    with pytest.raises(ValueError, match=r"seeds=\[1, 1\]: allowed: distinct integers >= 0"):
        sweep_runs(["paper"], [1, 1], tmp_path)


def test_the_table_has_one_row_per_candidate_over_its_seeds(tmp_path):
    runs = sweep_runs(["paper", "lr-decay"], [0, 1], tmp_path)
    scores = {("paper", 0): 2.0, ("paper", 1): 3.0, ("lr-decay", 0): 1.0, ("lr-decay", 1): 1.5}
    for run in runs:
        run.out.mkdir()
        score = scores[run.candidate, run.seed]
        metrics = {"validation_score": score, "rmse": score / 2, "improvement_rmse_xy_pct": 10 * score,
                   "improvement_rmse_z_pct": -score, "win_rate": 0.5, "crashed": run.seed}
        (run.out / "policy.json").write_text(json.dumps({"metrics": metrics}))
    write_table(runs, tmp_path / "table.json")
    rows = json.loads((tmp_path / "table.json").read_text())["rows"]
    assert [r["candidate"] for r in rows] == ["paper", "lr-decay"] and rows[0]["seeds"] == [0, 1]
    assert rows[1]["summary"]["validation_score"] == {"mean": 1.25, "min": 1.0, "max": 1.5}
    assert rows[0]["summary"]["crashed"]["max"] == 1.0
    md = (tmp_path / "table.md").read_text().splitlines()
    assert len(md) == 4 and md[2].startswith("| paper | `--lr-schedule constant` | 0, 1 | 2.500 (2.000 to 3.000) | +25.0")
    assert all(not math.isnan(v) for r in rows for v in r["values"]["rmse"])


@pytest.mark.slow
def test_a_toy_sweep_on_ray_trains_each_run_and_writes_the_rows(tmp_path):
    """Two candidates, one seed, toy PPO runs as Ray tasks on a local Ray instance (a few minutes)."""
    pytest.importorskip("ray")
    run = subprocess.run([sys.executable, str(ROOT / "recipes" / "recipe_sweep.py"), "--regime", "horizontal", "--quick",
                          "--candidates", "paper", "lr-decay", "--seeds", "0", "--out", str(tmp_path), "--executor", "ray"],
                         cwd=ROOT, capture_output=True, text=True, timeout=900,
                         env={**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))})
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    rows = json.loads((tmp_path / "recipe_sweep_horizontal.json").read_text())["rows"]
    assert [r["candidate"] for r in rows] == ["paper", "lr-decay"]
    times = json.loads((tmp_path / "pipeline_times.json").read_text())
    assert set(times) >= {"paper-seed0", "lr-decay-seed0"} and all("ray_node" in times[n] for n in ("paper-seed0", "lr-decay-seed0"))
    for name in ("paper", "lr-decay"):
        assert json.loads((tmp_path / f"{name}_seed0" / "policy.json").read_text())["ppo_config"]["lr_schedule"] == (
            "constant" if name == "paper" else "linear")
