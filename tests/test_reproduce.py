"""The whole pipeline end to end at toy scale: ``recipes/reproduce.py --quick`` (datasets ->
estimators -> PPO -> paired ablation with PD -> toy report -> summary), in a fresh directory."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_quick_reproduce_runs_every_stage(tmp_path):
    out = tmp_path / "quick"
    run = subprocess.run(
        [sys.executable, str(ROOT / "recipes" / "reproduce.py"), "--quick", "--out", str(out)],
        cwd=ROOT, capture_output=True, text=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])},
    )
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert "skipping" not in run.stdout  # every stage ran here, none was found done
    for regime in ("horizontal", "vertical"):
        assert (out / f"estimator_{regime}.pt").exists()
        assert (out / f"ppo_{regime}" / "policy.pt").exists()
    # the horizontal PPO recipe as shipped, at --quick scale (its own test would fly it again)
    m = json.loads((out / "ppo_horizontal" / "policy.json").read_text())
    assert m["frames"] == 1024 and m["env_spec"]["regime"] == "horizontal" and m["metrics"]["episodes"] == 1
    assert m["env_spec"]["env_config"]["reward"]["w_z"] == 1.0
    assert m["env_spec"]["env_config"]["controller"]["feedback"] == "estimate"  # the shipped vehicle by default
    for sweep in ("horizontal", "vertical"):
        result = json.loads((out / "results" / f"ablation_{sweep}.json").read_text())
        dist = result["rmse_xy"]["distribution"]
        assert set(dist) >= {"pd", "blind", "aware"}
        for controller in dist.values():
            assert controller["n"] > 0 and math.isfinite(controller["mean"]) and controller["mean"] > 0
    report = (out / "results.md").read_text()
    assert report.startswith("# Toy run: not the paper's results")
    for absent in ("225", "144", "ratio", "paper:", " 0 min", "simulator.md"):  # nothing it did not fly, no dead link
        assert absent not in report, absent
    assert "| horizontal | 10 |" in report and "RMSE reduction" in report
    assert (out / "figures" / "learning_curves.png").exists()
    # the closing summary: key numbers and the files to open
    summary = run.stdout[run.stdout.index("Toy run summary"):]
    assert "RMSE reduction" in summary and str(out / "results.md") in summary and "figures" in summary
    # the ablation's results replay: its batch re-flown from what the file records agrees to the bit
    check = subprocess.run(
        [sys.executable, str(ROOT / "recipes" / "ablation.py"), "--verify", str(out / "results" / "ablation_horizontal.json")],
        cwd=ROOT, capture_output=True, text=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])},
    )
    assert check.returncode == 0, check.stdout[-3000:] + check.stderr[-3000:]
    for name in ("pd", "blind", "aware"):
        assert f"  {name}: 40/40 values bit-identical" in check.stdout, check.stdout
