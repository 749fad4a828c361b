"""The observer's bound: an unfiltered observer and a perfect accelerometer (ControllerConfig), the
study that flies the best classical base with each idealisation, and its recipe. Eager, a few
rows, short flights."""
from __future__ import annotations

import json
import runpy
import sys
from dataclasses import replace

import pytest
import torch

from quadwind_trl.config import ControllerConfig, EnvConfig, TrajectoryConfig, TurbulenceConfig
from quadwind_trl.envs import QuadWindEnv, make_scenarios
from quadwind_trl.envs.controller import ControlInputs, make_base_controller
from quadwind_trl.envs.trajectories.library import Reference
from quadwind_trl.quick import SWEEP_QUICK
from quadwind_trl.regimes import VALIDATION_SWEEPS
from quadwind_trl.rl.paired import validation_scenarios
from quadwind_trl.studies.base_search import per_row_controller
from quadwind_trl.studies.observer_bound import (REFERENCE, VARIANTS, base_law, bound_rows, bound_table,
                                                costliest_episodes, fly_variants)


def test_an_unfiltered_observer_takes_the_whole_force_in_one_step():
    """``observer_tau_s = 0``: the filter's step gain is 1, so the estimate is the raw force of
    the instant it read (a constant push on a level vehicle, exactly)."""
    cfg = EnvConfig()
    law = make_base_controller(ControllerConfig(disturbance="observer", observer_tau_s=0.0), cfg.vehicle,
                               cfg.timing.control_dt_s)
    mass = cfg.vehicle.mass_kg
    weight = mass * 9.81
    state = law.init_state(1, torch.device("cpu"))
    push = torch.tensor([[1.5, -0.5, 0.0]])
    ref = Reference(*(torch.zeros(1, 3),) * 4, torch.zeros(1, 1), torch.zeros(1, 1))
    x = ControlInputs(torch.zeros(1, 3), torch.zeros(1, 3), torch.eye(3).expand(1, 3, 3), torch.zeros(1, 3), ref,
                      (push + torch.tensor([[0.0, 0.0, weight]])) / mass, torch.full((1, 1), weight), None,
                      torch.ones(1, 1, dtype=torch.bool), False)
    _, state = law(x, state)
    torch.testing.assert_close(state["force_hat"], push, rtol=1e-5, atol=1e-5)


def _force_hat_spread(reads: str) -> torch.Tensor:
    """The horizontal spread (N, std over 1 s) of an unfiltered observer's force, hovering in still
    air on the noisy sensors, reading the accelerometer or the true specific force."""
    cfg = EnvConfig(turbulence=TurbulenceConfig(enabled=False), trajectories=TrajectoryConfig(hover_duration_s=3.0),
                    controller=ControllerConfig(disturbance="observer", observer_tau_s=0.0, observer_reads=reads))
    env = QuadWindEnv(cfg, batch_size=[1])
    td = env.reset(scenario=make_scenarios(1, traj_id="hover", altitude_m=20.0, wind_speed_ref_m_s=0.0,
                                           turb_intensity=0.0, start_step=-1))
    hats = []
    for k in range(150):
        td = env.step(td.update({"action": torch.zeros(1, 4)}))["next"]
        if k >= 50:  # after the first half second
            hats.append(env.state["base", "force_hat"][0, :2].clone())
    return torch.stack(hats).std(0)


def test_a_perfect_accelerometer_takes_the_sensors_noise_out_of_the_observer():
    """Unfiltered on the real accelerometer, the observer's horizontal force carries the sensor's
    white noise times the mass (0.05 m/s^2 x 2.59 kg = 0.13 N); on the true specific force that
    term is gone and what is left is the real force of the hover's own small motions."""
    cfg = EnvConfig()
    noise_n = cfg.sensors.accel.noise_std * cfg.vehicle.mass_kg
    measured, perfect = _force_hat_spread("accelerometer"), _force_hat_spread("true_specific_force")
    assert (measured > 0.8 * noise_n).all() and (measured < 1.5 * noise_n).all()
    assert (perfect < 0.5 * noise_n).all()


def test_a_search_batch_refuses_candidates_that_read_differently():
    """What the observer reads is the simulator's setting, one per env: a batch mixing two is refused."""
    dob = ControllerConfig(disturbance="observer")
    with pytest.raises(ValueError, match="what they read"):
        per_row_controller([dob, replace(dob, observer_reads="true_specific_force")], torch.arange(2), EnvConfig())


@pytest.fixture(scope="module")
def rows():
    scenarios = validation_scenarios("horizontal", 2)
    scenarios = SWEEP_QUICK.scenarios(scenarios, VALIDATION_SWEEPS["horizontal"].ranges.top_altitude_m)
    config = SWEEP_QUICK.config(EnvConfig())
    picked = [v for v in VARIANTS if v.name in (REFERENCE, "unfiltered", "true_state_unfiltered", "still_air")]
    return bound_rows(fly_variants("horizontal", scenarios, config, picked), picked, resamples=200), config


def test_the_variants_fly_the_chosen_law_with_one_idealisation_each(rows):
    """The reference is the regime's chosen ``dob_inner``; every gain is over it on the same
    episodes; with the navigation error gone the error falls to a small part of it (the quick
    flights' RMSE is mostly navigation error), and still air is flown on the still scenarios."""
    rows, config = rows
    law = base_law("horizontal", config)
    assert law.disturbance == "observer" and law.k_att != config.controller.k_att
    by_name = {r["variant"]: r for r in rows}
    ref = by_name[REFERENCE]
    assert ref["xy"]["gain_pct"] == 0.0 and ref["xy"]["wins"] == 0 and ref["crashed"] == 0
    assert by_name["true_state_unfiltered"]["xy"]["rmse_m"] < 0.5 * ref["xy"]["rmse_m"]
    assert by_name["unfiltered"]["xy"]["rmse_m"] != ref["xy"]["rmse_m"]
    assert by_name["still_air"]["wind"] == "still"
    assert all(r["xy"]["episodes"] == 2 for r in rows)
    table = bound_table(rows)
    assert table.count("\n") == len(rows) + 1 and "`true_state_unfiltered`" in table


def test_rows_need_the_reference():
    with pytest.raises(ValueError, match=REFERENCE):
        bound_rows({}, VARIANTS)


def test_the_recipe_writes_its_rows_and_tables(tmp_path, monkeypatch):
    """``--quick``: three episodes of short flights, every variant, a JSON file with the command
    and commit, and the markdown tables."""
    monkeypatch.setattr(sys, "argv", ["recipes/observer_bound.py", "--quick", "--regimes", "horizontal",
                                      "--results", str(tmp_path)])
    runpy.run_path("recipes/observer_bound.py", run_name="__main__")
    report = json.loads((tmp_path / "observer_bound_horizontal.json").read_text())
    assert [r["variant"] for r in report["variants"]] == [v.name for v in VARIANTS]
    assert report["base"] == "dob_inner" and report["episodes"] == 3 and "observer_bound.py" in report["command"]
    assert len(report["per_episode"]["rmse_xy"]["still_air"]) == 3 and report["per_episode"]["traj_id"][0].endswith("_h")
    assert "**horizontal** (3 validation episodes" in (tmp_path / "observer_bound.md").read_text()


def test_the_costliest_episodes_are_where_the_wind_costs_most():
    """The per-episode table names each episode's world, and the episodes where the wind costs the
    law most come first, with their share of the sweep's summed cost."""
    episodes = {"traj_id": ["a", "b", "c"], "wind_speed_ref_m_s": [2.0, 10.0, 6.0], "turb_intensity": [0.1, 0.25, 0.1],
                "altitude_m": [50.0, 600.0, 100.0],
                "rmse_xy": {REFERENCE: [0.20, 1.00, 0.30], "still_air": [0.21, 0.40, 0.20]}}
    top = costliest_episodes(episodes, k=2)
    assert [e["episode"] for e in top] == [1, 2] and top[0]["traj_id"] == "b"
    assert top[0]["share_pct"] == pytest.approx(100.0 * 0.6 / 0.69) and top[1]["share_pct"] == pytest.approx(100.0 * 0.1 / 0.69)


def test_the_results_page_shows_each_regimes_bound(tmp_path, monkeypatch):
    """The results page's section reads every regime's file under ``results/`` (the experiments
    folder included): its table, command and the costliest episodes."""
    from quadwind_trl.studies.observer_bound import SECTION
    from quadwind_trl.studies.report import PAGE
    from quadwind_trl.studies.section import ReportContext

    monkeypatch.setattr(sys, "argv", ["recipes/observer_bound.py", "--quick", "--regimes", "horizontal",
                                      "--results", str(tmp_path / "experiments" / "observer_bound")])
    runpy.run_path("recipes/observer_bound.py", run_name="__main__")
    assert SECTION in PAGE
    text = SECTION.render(ReportContext(tmp_path, tmp_path / "sections", {}))
    assert "**horizontal** (3 validation episodes" in text and "`results/experiments/observer_bound/observer_bound_horizontal.json`" in text
    assert text.count("| `") == len(VARIANTS) and "Where the wind costs the law most" in text
