"""The residual on a classical base against that base and the paper's PD: the join of a seed's
ablation file with the classical controllers' file, and its statistics."""
from __future__ import annotations

import json

import pytest
import torch

from quadwind_trl.studies.residual import analyse_residual, joined_episodes, zero_residual_check

N = 6
PLATFORM = {"cpu": "test", "vector_isa": "AVX2"}


def _world() -> dict:
    return {"trajectory": ["loiter_circle_h"] * N, "case_id": list(range(N)), "turb_intensity": [0.1] * N,
            "wind_speed_ref_m_s": [4.0] * (N // 2) + [8.0] * (N // 2)}


def _rows(name: str, xy: torch.Tensor, z: torch.Tensor, crashed: int = 0) -> dict:
    return {f"{name}_rmse_xy": xy.tolist(), f"{name}_rmse_z": z.tolist(), f"{name}_rmse": (xy + z).tolist(),
            f"{name}_crashed": [i < crashed for i in range(N)]}


BASE_XY = torch.linspace(0.3, 0.8, N, dtype=torch.float64)
BASE_Z = torch.linspace(0.1, 0.2, N, dtype=torch.float64)


def _classical() -> dict:
    table = _world() | _rows("pd", 2.0 * BASE_XY, 2.0 * BASE_Z, crashed=1) | _rows("dob", BASE_XY, BASE_Z)
    return {"sweep": "horizontal", "controllers": ["pd", "dob"], "episodes_table": table, "platform": PLATFORM, "batch": N}


def _residual(aware: float, blind: float) -> dict:
    """A seed's residual ablation: its zero residual is the observer's row; the wind-aware
    residual removes ``aware`` of the base's xy RMSE on every episode, the trained-blind ``blind``;
    both keep the base's height error."""
    table = (_world() | _rows("pd", BASE_XY, BASE_Z) | _rows("aware", (1 - aware) * BASE_XY, BASE_Z)
             | _rows("trained_blind", (1 - blind) * BASE_XY, BASE_Z))
    return {"sweep": "horizontal", "controllers": ["pd", "aware", "trained_blind"], "episodes_table": table,
            "platform": PLATFORM, "batch": N}


def test_the_residual_is_paired_with_its_base_and_with_the_papers_pd():
    analysis = analyse_residual({"0": _residual(0.2, 0.1), "1": _residual(0.3, 0.1)}, _classical(), "dob", resamples=50)
    every = analysis["by_wind"]["all"]
    assert every["aware_vs_base"]["across_seeds"]["mean"] == pytest.approx(25.0)
    assert every["trained_blind_vs_base"]["across_seeds"]["mean"] == pytest.approx(10.0)
    # against a PD with twice the base's error: 1 - (1 - a) / 2
    assert every["aware_vs_paper_pd"]["per_seed"]["0"]["improvement"] == pytest.approx(60.0)
    assert every["aware_vs_trained_blind"]["per_seed"]["1"]["improvement"] == pytest.approx(100 * (1 - 0.7 / 0.9))
    assert sorted(analysis["by_wind"]) == ["4", "8", "all"] and analysis["base"] == "dob"
    overall = analysis["overall"]["0"]
    assert overall["rmse_xy"]["aware_vs_base"]["wins"] == N and overall["rmse_xy"]["aware_vs_base"]["n"] == N
    assert overall["rmse_z"]["aware_vs_base"]["improvement"] == pytest.approx(0.0)
    assert overall["rmse_z"]["aware_vs_paper_pd"]["improvement"] == pytest.approx(50.0)
    assert overall["rmse_xy"]["worst"] == pytest.approx({"paper_pd": 1.6, "base": 0.8, "aware": 0.64, "trained_blind": 0.72})
    assert overall["crashed"] == {"paper_pd": 1, "base": 0, "aware": 0, "trained_blind": 0}
    assert analysis["zero_residual"]["0"] == {"max_abs_diff_m": {"rmse_xy": 0.0, "rmse_z": 0.0}, "bitwise": True,
                                              "same_platform": True, "same_batch": True}


def test_a_zero_residual_off_the_base_row_is_measured():
    residual = _residual(0.2, 0.1)
    residual["episodes_table"]["pd_rmse_xy"][2] += 1e-6
    check = zero_residual_check(residual, _classical(), "dob")
    assert not check["bitwise"] and check["max_abs_diff_m"]["rmse_xy"] == pytest.approx(1e-6)


def test_files_of_other_episodes_or_without_the_base_are_refused():
    residual = _residual(0.2, 0.1)
    residual["episodes_table"]["wind_speed_ref_m_s"] = residual["episodes_table"]["wind_speed_ref_m_s"][::-1]
    with pytest.raises(ValueError, match="column 'wind_speed_ref_m_s' differs"):
        joined_episodes(residual, _classical(), "dob")
    with pytest.raises(ValueError, match="not the base 'pid'"):
        joined_episodes(_residual(0.2, 0.1), _classical(), "pid")


def test_the_report_section_renders_every_seed_the_goal_and_the_check():
    from quadwind_trl.studies.residual import residual_section

    analysis = analyse_residual({"0": _residual(0.2, 0.1), "1": _residual(0.3, 0.1)}, _classical(), "dob", resamples=50)
    text = residual_section({"command": "python recipes/residual_value.py --base dob", "git_commit": "abc", "base": "dob",
                             "sweeps": {"horizontal": analysis}})
    rows = [line for line in text.splitlines() if line.startswith("| ")]
    assert any(r.startswith("| 0 | +20.0 (") and r.endswith("| 1.60 / 0.80 / 0.64 | 1 / 0 / 0 |") for r in rows)
    # seed 1 removes 30 % with every episode won and z unchanged; seed 0 falls short of 25 %
    assert "met by 1 of 2 seeds (1)." in text
    assert any(r.startswith("| all | +25.0 (+20.0 to +30.0) |") for r in rows)
    assert "equal to the bit for seeds 0, 1" in text


def test_the_training_table_says_what_a_residual_on_a_classical_base_is_measured_against():
    from quadwind_trl.studies.training import training_section

    def manifest(controller: dict) -> dict:
        return {"command": "python recipes/ppo_horizontal.py", "git_commit": "abc", "frames": 1, "wall_time_s": 60.0,
                "evals": [], "env_spec": {"env_config": {"controller": controller}}}

    rows = training_section({"on_pd": manifest({}), "on_dob": manifest({"disturbance": "observer"}),
                             "on_pid_ff": manifest({"ki_pos": [2.0, 2.0, 2.0], "disturbance": "wind_model"})}).splitlines()
    assert any(r.startswith("| on_pd | ") for r in rows)
    assert any(r.startswith("| on_dob (against its base, PD + disturbance observer) |") for r in rows)
    assert any(r.startswith("| on_pid_ff (against its base, PD + integral + wind feed-forward) |") for r in rows)


def test_the_residual_is_compared_per_pattern_flown():
    """Where the residual helps on one pattern only, the pattern rows say so and the rows of all
    episodes average the two."""
    patterns = ["loiter_circle_h", "figure8_h"] * (N // 2)
    removed = torch.tensor([0.0 if p == "loiter_circle_h" else 0.4 for p in patterns], dtype=torch.float64)

    def on_patterns(result: dict) -> dict:
        result["episodes_table"]["trajectory"] = patterns
        return result

    residual = _residual(0.0, 0.0)
    residual["episodes_table"] |= _rows("aware", (1 - removed) * BASE_XY, BASE_Z)
    analysis = analyse_residual({"0": on_patterns(residual), "1": on_patterns(_residual(0.1, 0.1))},
                                on_patterns(_classical()), "dob", resamples=50)
    by_pattern = analysis["by_trajectory"]
    # registered order, then every episode
    assert list(by_pattern) == ["loiter_circle_h", "figure8_h", "all"]
    assert by_pattern["figure8_h"]["aware_vs_base"]["per_seed"]["0"]["improvement"] == pytest.approx(40.0)
    assert by_pattern["loiter_circle_h"]["aware_vs_base"]["per_seed"]["0"]["improvement"] == pytest.approx(0.0)
    assert by_pattern["loiter_circle_h"]["aware_vs_base"]["across_seeds"]["mean"] == pytest.approx(5.0)
    assert by_pattern["all"]["aware_vs_base"]["per_seed"]["1"]["improvement"] == pytest.approx(10.0)

    from quadwind_trl.studies.residual import residual_section

    # as the results file keeps it: keys sorted by name
    stored = json.loads(json.dumps({"command": "c", "git_commit": "abc", "base": "dob", "sweeps": {"horizontal": analysis}},
                                   sort_keys=True))
    text = residual_section(stored)
    assert "xy by pattern over all wind levels" in text
    rows = [line for line in text.splitlines() if line.startswith(("| loiter_circle_h |", "| figure8_h |"))]
    assert len(rows) == 2 and rows[0].startswith("| loiter_circle_h | +5.0 (+0.0 to +10.0) |")
    assert rows[1].startswith("| figure8_h | +25.0 (+10.0 to +40.0) |")
