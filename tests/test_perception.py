"""What the wind estimate is worth: flight phases of a flight record, the across-seed
statistics of the paired ablation, and the report section drawn from them."""
from __future__ import annotations

import math

import pytest
import torch
from scipy import stats
from tensordict import TensorDict

from quadwind_trl.evaluation.ablation import episode_table_from_json
from quadwind_trl.evaluation.phases import PhaseConfig, masked_sse_xy, phase_masks, phase_rmse
from quadwind_trl.evaluation.statistics import t_interval
from quadwind_trl.studies.perception import (analyse_sweep, episode_groups, feedforward_by_wind, feedforward_value_table,
                                            perception_section, variant_change)

DT = 0.1  # the 10 Hz record
SPEED = 10.0  # m/s, the patterns' cruise speed
RADIUS = 60.0  # m: the loiter circle, 9.5 deg/s at cruise


def _line(start: float, velocity: float, n: int) -> torch.Tensor:
    """``[n, 2]`` a straight leg along x (east) at ``velocity`` m/s."""
    x = start + velocity * DT * torch.arange(n, dtype=torch.float64)
    return torch.stack((x, torch.zeros_like(x)), -1)


def _arc(n: int, first: int = 0) -> torch.Tensor:
    """``[n, 2]`` samples ``first..first+n-1`` of a counter-clockwise circle flown at cruise from
    the origin heading east (centre due north)."""
    phase = SPEED * DT * torch.arange(first, first + n, dtype=torch.float64) / RADIUS
    return torch.stack((RADIUS * torch.sin(phase), RADIUS - RADIUS * torch.cos(phase)), -1)


def _record(paths: list[torch.Tensor], valid: torch.Tensor, wind_east: float = 5.0) -> TensorDict:
    """A flight record of reference paths ``[T, 2]`` each (altitude 20 m), flown exactly, a mean
    wind blowing towards the east (from the west) and every sample after the pattern start."""
    n, t = len(paths), paths[0].shape[0]
    ref = torch.cat((torch.stack(paths), torch.full((n, t, 1), 20.0, dtype=torch.float64)), -1).float()
    wind = torch.tensor([wind_east, 0.0, 0.0]).expand(n, t, 3).clone()
    return TensorDict({"ref_pos": ref, "truth": {"pos": ref.clone(), "mean_wind": wind},
                       "step": (10 * torch.arange(t)).expand(n, t).unsqueeze(-1).clone(), "valid": valid}, batch_size=[n, t])


def test_turns_and_straight_legs_are_counted_from_the_reference_heading_rate():
    t = 60
    straight_then_turn = torch.cat((_line(-29 * SPEED * DT, SPEED, 30), _arc(t - 30, 1)))  # straight to the origin, then the circle
    valid = torch.ones(2, t, dtype=torch.bool)
    valid[1, -10:] = False  # the second flight ended 10 samples early (the record holds its last sample)
    east = _line(0.0, SPEED, t)
    east[-10:] = east[-11]
    log = _record([straight_then_turn, east], valid)
    masks = phase_masks(log, pattern_start=torch.tensor([-1, -1]))
    # the first sample has no predecessor; samples 1-28 fly straight, sample 29 (the origin, where
    # the circle starts) turns by half an arc step (4.8 deg/s), every later one by 9.5 deg/s; the
    # last has no successor
    assert masks["straight"][0].nonzero().flatten().tolist() == list(range(1, 29))
    assert masks["turn"][0].nonzero().flatten().tolist() == list(range(29, t - 1))
    # the ended flight: its last valid sample has no successor in the record
    assert masks["straight"][1].nonzero().flatten().tolist() == list(range(1, t - 11))
    assert not masks["turn"][1].any()


def test_pattern_start_and_slow_reference_get_no_phase():
    t = 40
    creep = _line(0.0, 0.5 * PhaseConfig().min_speed_m_s, t)  # a slow reference (a climb, the start of the ramp)
    cruise = _line(0.0, SPEED, t)
    log = _record([creep, cruise], torch.ones(2, t, dtype=torch.bool))
    masks = phase_masks(log, pattern_start=torch.tensor([-1, 100]))  # the second flight's pattern starts at step 100
    assert not any(m[0].any() for m in masks.values())
    assert masks["straight"][1].nonzero().flatten().tolist() == list(range(11, t - 1))  # steps 110 onwards


def test_headwind_is_flying_into_the_wind():
    t = 30
    log = _record([_line(0.0, SPEED, t), _line(0.0, -SPEED, t)], torch.ones(2, t, dtype=torch.bool))  # east, west
    masks = phase_masks(log, pattern_start=torch.tensor([-1, -1]))
    inner = list(range(1, t - 1))
    # the wind blows from the west: flying east it pushes from behind, flying west into it
    assert masks["tailwind"][0].nonzero().flatten().tolist() == inner and not masks["headwind"][0].any()
    assert masks["headwind"][1].nonzero().flatten().tolist() == inner and not masks["tailwind"][1].any()
    assert not masks["crosswind"].any()


def test_a_full_circle_splits_into_quarter_headwind_half_crosswind_quarter_tailwind():
    t = round(2 * math.pi * RADIUS / (SPEED * DT)) + 2
    log = _record([_arc(t)], torch.ones(1, t, dtype=torch.bool))
    masks = phase_masks(log, pattern_start=torch.tensor([-1]))
    counts = {p: int(masks[p].sum()) for p in ("headwind", "crosswind", "tailwind")}
    inner = t - 2
    assert sum(counts.values()) == inner
    assert counts["headwind"] == pytest.approx(inner / 4, abs=2) and counts["tailwind"] == pytest.approx(inner / 4, abs=2)
    assert int(masks["turn"].sum()) == inner and not masks["straight"].any()


def test_rmse_per_phase_is_the_rms_of_the_horizontal_error_over_its_samples():
    t = 60
    log = _record([torch.cat((_line(-29 * SPEED * DT, SPEED, 30), _arc(t - 30, 1)))], torch.ones(1, t, dtype=torch.bool))
    err = torch.zeros(1, t, 3)
    err[0, :29] = torch.tensor([0.3, 0.4, 5.0])  # the height error is not horizontal error
    err[0, 29:, 0] = torch.linspace(0.0, 3.0, t - 29)
    log["truth", "pos"] = log["ref_pos"] + err
    masks = phase_masks(log, pattern_start=torch.tensor([-1]))
    turn = [float(e) for e in err[0, 29:t - 1, 0]]  # samples 29 to T-2
    for phase, hand in (("straight", 0.5), ("turn", math.sqrt(sum(e * e for e in turn) / len(turn)))):
        sse, count = masked_sse_xy(log, masks[phase])
        assert phase_rmse(sse, count).item() == pytest.approx(hand, rel=1e-6)
        assert count.item() == int(masks[phase].sum())
    sse, count = masked_sse_xy(log, masks["headwind"] & False)
    assert sse.item() == 0.0 and count.item() == 0 and math.isnan(phase_rmse(sse, count).item())


def test_phase_config_names_the_field_and_its_range():
    with pytest.raises(ValueError, match=r"PhaseConfig.tailwind_min_deg=30.0 is outside the allowed range \[45.0, 180.0\]"):
        phase_masks(_record([_line(0.0, SPEED, 5)], torch.ones(1, 5, dtype=torch.bool)), torch.tensor([-1]),
                    PhaseConfig(tailwind_min_deg=30.0))


def test_t_interval_is_students_with_n_minus_one_degrees_of_freedom():
    low, high = t_interval([1.0, 2.0, 3.0])
    half = stats.t.ppf(0.975, 2) * 1.0 / math.sqrt(3)  # sd 1
    assert (low, high) == pytest.approx((2.0 - half, 2.0 + half))
    assert half == pytest.approx(2.4841, abs=1e-4)
    assert all(math.isnan(x) for x in t_interval([5.0]))


WINDS = (4.0, 6.0)
PER_WIND = 4


def _seed(value: float, oracle: float | None, phases: bool = True) -> dict:
    """An ablation results file of one seed: the wind-aware policy removes ``value`` of the
    trained-blind policy's RMSE on every episode (and the oracle-trained one ``oracle``)."""
    n = len(WINDS) * PER_WIND
    trained_blind = torch.linspace(0.5, 1.2, n, dtype=torch.float64)
    table = {"trajectory": ["loiter_circle_h"] * n, "case_id": list(range(n)), "turb_intensity": [0.1] * n,
             "wind_speed_ref_m_s": [w for w in WINDS for _ in range(PER_WIND)],
             "pd_rmse_xy": (2.0 * trained_blind).tolist(), "blind_rmse_xy": (1.1 * trained_blind).tolist(),
             "trained_blind_rmse_xy": trained_blind.tolist(), "aware_rmse_xy": ((1 - value) * trained_blind).tolist()}
    if oracle is not None:
        table["trained_oracle_rmse_xy"] = ((1 - oracle) * trained_blind).tolist()
    if phases:
        for controller in ("trained_blind", "aware"):
            # every episode's turn RMSE is its whole RMSE over 100 samples; the first has no turn
            table[f"{controller}_sse_xy_turn"] = [0.0] + [100.0 * r * r for r in table[f"{controller}_rmse_xy"][1:]]
            table[f"{controller}_samples_turn"] = [0.0] + [100.0] * (n - 1)
    return {"sweep": "horizontal", "episodes_table": table}


@pytest.fixture(scope="module")
def analysis():
    return analyse_sweep({"0": _seed(0.1, 0.3), "1": _seed(0.2, 0.4), "2": _seed(0.3, None)}, resamples=200)


def test_across_seeds_the_value_is_the_seed_mean_with_its_t_interval(analysis):
    row = analysis["by_wind"]["all"]
    value = row["aware_vs_trained_blind"]
    assert [value["per_seed"][s]["improvement"] for s in "012"] == pytest.approx([10.0, 20.0, 30.0])
    across = value["across_seeds"]
    assert across["n_seeds"] == 3 and across["mean"] == pytest.approx(20.0)
    assert (across["min"], across["max"]) == pytest.approx((10.0, 30.0))
    assert (across["t_low"], across["t_high"]) == pytest.approx(t_interval([10.0, 20.0, 30.0]))
    assert value["pooled"]["improvement"] == pytest.approx(20.0) and value["pooled"]["wins"] == len(WINDS) * PER_WIND
    # the oracle-trained policy only where a seed trained one
    assert row["trained_oracle_vs_trained_blind"]["across_seeds"]["n_seeds"] == 2
    assert row["trained_oracle_vs_trained_blind"]["across_seeds"]["mean"] == pytest.approx(35.0)
    # zeroing: (blind - aware) / (PD - aware) of the group means, PD = 2, blind = 1.1, aware = 1 - v
    assert row["zeroing_share"]["per_seed"]["0"] == pytest.approx(100 * (1.1 - 0.9) / (2.0 - 0.9))
    assert row["trained_share"]["per_seed"]["0"] == pytest.approx(100 * (1.0 - 0.9) / (2.0 - 0.9))
    assert row["paper_zeroing_share"] == 47.6 and analysis["by_wind"]["4"]["paper_zeroing_share"] == 38.0
    assert sorted(analysis["by_wind"]) == ["4", "6", "all"]


def test_a_phase_is_compared_on_the_episodes_that_flew_it(analysis):
    turn = analysis["by_phase"]["turn"]
    assert turn["4"]["aware_vs_trained_blind"]["per_seed"]["0"]["n"] == PER_WIND - 1
    assert turn["all"]["aware_vs_trained_blind"]["across_seeds"]["mean"] == pytest.approx(20.0)
    assert analysis["phase_samples_per_episode"]["turn"] == pytest.approx(100.0 * 7 / 8)
    assert list(analysis["by_phase"]) == ["turn"]


def test_seeds_of_other_episodes_are_refused():
    other = _seed(0.2, None)
    other["episodes_table"]["case_id"] = other["episodes_table"]["case_id"][::-1]
    with pytest.raises(ValueError, match="seed 1's episode table lists other episodes than seed 0's"):
        analyse_sweep({"0": _seed(0.1, None), "1": other}, resamples=10)


def test_a_variant_is_compared_with_the_base_recipe_on_the_same_seeds(analysis):
    # base seeds 0-2 are worth 10 / 20 / 30 %; the variant trained seeds 0 and 1 only
    variant = analyse_sweep({"0": _seed(0.4, None, False), "1": _seed(0.6, None, False)}, resamples=10)
    change = variant_change(analysis, variant)["all"]
    assert change["seeds"] == ["0", "1"]  # seed 2, which the variant lacks, weighs on neither side
    assert change["change"] == pytest.approx(35.0) and change["base_mean"] == pytest.approx(15.0)
    assert (change["t_low"], change["t_high"]) == pytest.approx(t_interval([30.0, 40.0]))
    assert variant_change(analysis, analyse_sweep({"7": _seed(0.4, None, False)}, resamples=10)) == {}  # no seed in common


def test_the_report_section_renders_every_table(analysis):
    variant = analyse_sweep({"0": _seed(0.4, None, False), "1": _seed(0.5, None, False)}, resamples=10)
    variant["change_vs_base"] = variant_change(analysis, variant)
    result = {"command": "python recipes/perception_value.py", "git_commit": "abc", "figure": "docs/figures/perception_value.png",
              "inputs": {"base": {"horizontal": {s: {"git_commit": "f00"} for s in "012"}}},
              "sweeps": {"horizontal": analysis}, "variants": {"no_attitude_accel": {"sweeps": {"horizontal": variant}}}}
    text = perception_section(result)
    rows = [line for line in text.splitlines() if line.startswith("| ")]
    half = stats.t.ppf(0.975, 2) * 10 / math.sqrt(3)
    value_rows = [r for r in rows if r.startswith("| all | +20.0 (+10.0 to +30.0)")]
    assert value_rows and f"{20 - half:+.1f} to {20 + half:+.1f} (3)" in value_rows[0]
    assert "+35.0 (+30.0 to +40.0)" in value_rows[0]  # the oracle-trained policy's two seeds
    assert any(r.startswith("| 4 |") and r.endswith(" 38.0 |") for r in rows)  # the paper's zeroing share at 4 m/s
    assert any(r.startswith("| 2 | +30.0 (") and r.count(" | - |") == 1 for r in rows)  # seed 2 trained no oracle
    assert any(r.startswith("| turn | 88 |") for r in rows)
    change = [r for r in rows if r.startswith("| `no_attitude_accel` | horizontal | all |")]
    assert change and "| +30.0 (+30.0 to +30.0) (2) |" in change[0]  # on the two seeds both trained (base: 10, 20 %)
    assert change[0].count("|") == 10 and change[0].endswith(" 47.6 |")  # the variant's zeroing share, the paper's beside
    assert "![value of the estimate](figures/perception_value.png)" in text


def test_the_figure_draws_each_variant_beside_the_base_seeds(analysis, monkeypatch, tmp_path):
    import matplotlib.pyplot as plt

    from quadwind_trl.studies import perception as study

    variant = analyse_sweep({"0": _seed(0.4, None, False), "1": _seed(0.5, None, False)}, resamples=10)
    drawn = {}
    monkeypatch.setattr(study, "save_figure", lambda fig, path: drawn.setdefault("fig", fig) and path)
    study.perception_value({"horizontal": analysis}, tmp_path / "value.png",
                           {"no_attitude_accel": {"sweeps": {"horizontal": variant}}, "other_sweep_only": {"sweeps": {}}})
    value, share = drawn["fig"].axes
    labels = [[t.get_text() for t in panel.get_legend().get_texts()] for panel in (value, share)]
    assert any(t.startswith("no_attitude_accel: wind-aware vs trained blind (n = 2 seeds)") for t in labels[0])
    assert any(t.startswith("no_attitude_accel: zeroing share (n = 2 seeds)") for t in labels[1])
    assert not any("other_sweep_only" in t for t in labels[0] + labels[1])  # a variant that did not fly the sweep
    plt.close(drawn["fig"])


def _classical(estimate: float, oracle: float) -> dict:
    """A classical controllers' file of the seeds' episodes: PID + feed-forward on the estimate
    removes ``estimate`` of its blind twin's RMSE on every episode, on the true wind ``oracle`` of
    the estimate's."""
    table = {k: v for k, v in _seed(0.0, None, False)["episodes_table"].items() if not k.endswith("_rmse_xy")}
    blind = torch.linspace(0.4, 0.9, len(table["case_id"]), dtype=torch.float64)
    table["pid_ff_blind_rmse_xy"] = blind.tolist()
    table["pid_ff_rmse_xy"] = ((1 - estimate) * blind).tolist()
    table["pid_ff_oracle_rmse_xy"] = ((1 - oracle) * (1 - estimate) * blind).tolist()
    return {"sweep": "horizontal", "controllers": ["pid_ff", "pid_ff_blind", "pid_ff_oracle"], "episodes_table": table}


def test_the_feedforward_value_is_paired_per_wind_level_and_rendered_beside_the_policies(analysis):
    seeds = {"0": _seed(0.1, None)}
    ff = feedforward_by_wind(_classical(0.25, 0.04), seeds, resamples=50)
    assert sorted(ff) == ["4", "6", "all"]
    for row in ff.values():
        assert row["pid_ff"]["estimate_value"]["improvement"] == pytest.approx(25.0)
        assert row["pid_ff"]["oracle_value"]["improvement"] == pytest.approx(4.0)
    assert ff["4"]["pid_ff"]["estimate_value"]["n"] == PER_WIND and ff["all"]["pid_ff"]["estimate_value"]["wins"] == 8
    other = _classical(0.25, 0.04)
    other["episodes_table"]["case_id"] = other["episodes_table"]["case_id"][::-1]
    with pytest.raises(ValueError, match="other episodes"):
        feedforward_by_wind(other, seeds, resamples=10)
    rows = feedforward_value_table({**analysis, "feedforward": {"file": "results/classical/ablation_horizontal.json",
                                                                "git_commit": "abc", "by_wind": ff}})
    table = [r for r in rows if r.startswith("| ")]
    assert table[0].count("|") == 5  # U, the policies' value, the estimate's and the true wind's to PID + FF
    assert table[-1].startswith("| all | +20.0 | +25.0 (") and "8/8" in table[-1]


def test_episodes_group_by_wind_level_or_pattern_and_nothing_else():
    table = episode_table_from_json({"trajectory": ["figure8_h", "loiter_circle_h", "figure8_h"], "case_id": [0, 1, 2],
                                     "wind_speed_ref_m_s": [6.0, 4.0, 6.0]})
    by_wind, by_pattern = episode_groups(table), episode_groups(table, by="trajectory")
    assert list(by_wind) == ["4", "6", "all"] and by_wind["6"].tolist() == [True, False, True]
    assert list(by_pattern) == ["loiter_circle_h", "figure8_h", "all"] and by_pattern["loiter_circle_h"].tolist() == [False, True, False]
    with pytest.raises(ValueError, match=r"by='phase': expected one of wind, trajectory"):
        episode_groups(table, by="phase")
