"""The quickstart's first flight (``recipes/first_flight.py``): the shipped policy against PD on a
few paper-scale episodes, its statistics consistent with its own per-episode table."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from quadwind_trl.envs.trajectories import HORIZONTAL, trajectory_name
from quadwind_trl.evaluation.first_flight import FirstFlight, median_episode
from quadwind_trl.regimes import FIRST_FLIGHT_SEED

ROOT = Path(__file__).resolve().parent.parent


def test_first_flight_episodes_are_the_stated_world():
    sc = FirstFlight(episodes=7, wind_m_s=8.0, intensity=0.2).scenarios()
    assert sc.batch_size[0] == 7
    assert torch.all(sc["wind_speed_ref_m_s"] == 8.0) and torch.allclose(sc["turb_intensity"], torch.tensor(0.2))
    assert torch.all(sc["altitude_m"] == 100.0) and torch.all(sc["start_step"] == -1)  # airborne at the pattern start
    assert [trajectory_name(int(i)) for i in sc["traj_id"]] == [HORIZONTAL[i % len(HORIZONTAL)] for i in range(7)]
    assert sc["turb_seed"].unique().numel() == 7 and sc["wind_dir_deg"].unique().numel() == 7  # independent wind cases
    assert FirstFlight().seed == FIRST_FLIGHT_SEED


@pytest.mark.parametrize("field, value, message", [("episodes", 0, "episodes=0"), ("pattern_s", 0.0, "pattern_s=0.0"),
                                                   ("wind_m_s", -1.0, "wind_speed_m_s"), ("intensity", 5.0, "intensity")])
def test_first_flight_rejects_bad_settings_by_name(field, value, message):
    with pytest.raises(ValueError, match=message):
        FirstFlight(**{field: value})


def test_median_episode_is_the_median_reduction():
    pd = torch.tensor([1.0, 1.0, 1.0, 1.0])
    rl = torch.tensor([0.5, 0.9, 0.7, 0.2])  # reductions 50, 10, 30, 80 %: the lower median is 30 %
    assert median_episode(pd, rl) == 2


def test_first_flight_recipe_reports_the_paired_result(tmp_path):
    out = tmp_path / "first_flight"
    # 2 s of pattern (was 5): the report's consistency with its own episode table, checked below,
    # does not depend on how long the episodes are, and the flights were most of the recipe's run
    run = subprocess.run(
        [sys.executable, str(ROOT / "recipes" / "first_flight.py"), "--episodes", "2", "--seconds", "2", "--out", str(out)],
        cwd=ROOT, capture_output=True, text=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])},
    )
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    result = json.loads((out / "first_flight.json").read_text())
    assert (out / "first_flight.png").stat().st_size > 0
    assert result["command"].startswith("python recipes/first_flight.py --episodes 2 --seconds 2")
    assert "git_commit" in result and result["platform"]["torch_threads"] == 1
    assert result["controllers"] == ["pd", "aware"] and result["episodes"] == 2
    assert result["first_flight"] | {"flights": None} == {"episodes": 2, "pattern_s": 2.0, "wind_m_s": 10.0, "intensity": 0.15,
                                                          "seed": FIRST_FLIGHT_SEED, "flights": None}
    assert result["policy"] == "quadwind_trl/checkpoints/policy_horizontal.pt"
    # the paired improvement is what the per-episode RMSEs imply
    table = result["episodes_table"]
    pd, rl = torch.tensor(table["pd_rmse_xy"], dtype=torch.float64), torch.tensor(table["aware_rmse_xy"], dtype=torch.float64)
    xy = result["rmse_xy"]["aware"]
    assert xy["improvement"] == pytest.approx(100 * (1 - rl.mean().item() / pd.mean().item()), abs=1e-9)
    assert xy["wins"] == int((rl < pd).sum()) and xy["ci_low"] <= xy["improvement"] <= xy["ci_high"]
    assert result["shown_episode"] == median_episode(pd, rl)
    assert f"{xy['improvement']:+.1f} %" in run.stdout and "retrains everything at toy scale" in run.stdout
