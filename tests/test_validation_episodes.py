"""Several policies on one validation sweep (evaluation/policy_validation.py): PD flies once and
its episodes are every policy's, each policy keeps the metrics it gets validated alone, and each
episode's margin to the flight envelope is evaluation/envelope.py's. The flights are the shipped
horizontal policies (wind-aware and trained blind: one env config), 2 episodes, eager, with the
monitor, from the pattern start as ``--quick`` flies them but for a 1 s pattern (``QUICK``): the
comparisons are bit for bit, which a longer flight would not make stronger."""
from __future__ import annotations

import copy
import importlib.util
import json
import sys
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict

import quadwind_trl.evaluation.policy_validation as pv
from quadwind_trl.config import MonitorConfig
from quadwind_trl.envs.envelope import flight_envelope
from quadwind_trl.envs.trajectories import trajectory_name
from quadwind_trl.envs.simulator import trajectory_library
from quadwind_trl.estimator import load_estimator
from quadwind_trl.evaluation.ablation import WIND_INPUT, fly_controllers, policy_env_config
from quadwind_trl.evaluation.envelope import airspeed_demand, pattern_speed
from quadwind_trl.evaluation.policy_validation import (POLICY_CONTROLLERS, envelope_split, episode_envelope,
                                                       episode_rows, flight_altitude, monitor_authority,
                                                       validate_policies)
from quadwind_trl.keys import MONITOR_KEY
from quadwind_trl.quick import PPO_QUICK, QuickFlights
from quadwind_trl.rl.envs import DEFAULT_RANGES
from quadwind_trl.rl.paired import paired_metrics, validation_scenarios
from quadwind_trl.rl.policy import load_policy

ROOT = Path(__file__).resolve().parent.parent
CHECKPOINTS = ROOT / "quadwind_trl" / "checkpoints"
AWARE, BLIND = CHECKPOINTS / "policy_horizontal.pt", CHECKPOINTS / "policy_horizontal_trained_blind.pt"
VERTICAL = CHECKPOINTS / "policy_vertical.pt"
FLIGHT = dict(monitor=MonitorConfig(), episodes=2, quick=True, compile_step=False)  # the monitor's metrics too
QUICK = {"horizontal": QuickFlights(pattern_s=1.0, altitude_m=PPO_QUICK["horizontal"].altitude_m)}


def old_validate_policy(policy_path, *, monitor, episodes, quick, compile_step):
    """``validate_policy`` as it was before several policies could fly: PD and the policy in one
    ``fly_controllers`` call, in the policy's own env; the metrics and the flights. The episodes
    and the env change are ``validation_setup``'s (with ``QUICK``), which the old code built the
    same way: what differs is only how PD is flown."""
    payload = load_policy(policy_path)[1]
    spec = payload["env_spec"]
    regime = spec["regime"]
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(pv, "PPO_QUICK", QUICK)
        scenarios, override = pv.validation_setup(regime, episodes, quick, monitor)
    config = override(policy_env_config(payload))
    wind_input = spec.get("wind_input", "estimate")
    controller = next(c for c in POLICY_CONTROLLERS if WIND_INPUT[c] == wind_input)
    estimator = None if controller == "oracle" else load_estimator(
        regime, spec.get("estimator_path"), untrained=spec.get("untrained_estimator", False), config=config)
    flown = fly_controllers(regime, scenarios, policy_path, estimator, ("pd", controller), config_override=override,
                            compile_step=compile_step, log_keys=("step",) + ((MONITOR_KEY,) if monitor is not None else ()))
    metrics = paired_metrics(flown[controller], flown["pd"])
    if monitor is not None:
        pattern_start, _ = trajectory_library(config, torch.device("cpu")).schedule(scenarios["traj_id"],
                                                                                   scenarios["altitude_m"])
        metrics.update(monitor_authority(flown[controller], pattern_start))
    return metrics, flown


@pytest.fixture(scope="module")
def both():
    """Both policies validated together (PD flown with the wind-aware policy's env), and which
    controllers each ``fly_controllers`` call flew."""
    calls = []

    def counted(*args, **kwargs):
        calls.append(args[4])
        return fly_controllers(*args, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(pv, "fly_controllers", counted)
        mp.setattr(pv, "PPO_QUICK", QUICK)
        result = validate_policies([AWARE, BLIND], **FLIGHT)
    return result, calls


@pytest.fixture(scope="module", params=[AWARE, BLIND], ids=lambda p: p.stem)
def alone(request):
    """The old single-policy path on one policy: its PD flies in that policy's env (the label,
    the metrics and the flights)."""
    return (request.param.stem, *old_validate_policy(request.param, **FLIGHT))


def test_pd_flies_once_and_each_policy_once(both):
    result, calls = both
    assert calls == [("pd",), ("aware",), ("blind",)]  # the trained-blind policy flies as it trained: wind zeroed
    assert list(result.metrics) == ["policy_horizontal", "policy_horizontal_trained_blind"]


def test_pd_rows_are_the_same_whichever_policies_fly(both, alone):
    result, _ = both
    _, _, flown = alone
    pd = result.episodes["pd"]
    for key in ("rmse_xy", "rmse_z", "rmse", "crashed"):
        assert torch.equal(pd[key], getattr(flown["pd"], key)), key  # bit for bit


def test_each_policy_keeps_its_single_policy_metrics(both, alone):
    result, _ = both
    label, metrics, flown = alone
    assert result.metrics[label] == metrics  # every float exactly, the monitor's share included
    controller = next(name for name in flown if name != "pd")
    assert torch.equal(result.episodes["policies", label, "rmse"], flown[controller].rmse)


def test_episode_margins_are_the_envelope_modules(both):
    result, _ = both
    config = QUICK["horizontal"].config(policy_env_config(load_policy(AWARE)[1]))
    scenarios = QUICK["horizontal"].scenarios(validation_scenarios("horizontal", 2), DEFAULT_RANGES["horizontal"].top_altitude_m)
    demand = airspeed_demand(scenarios, config, pattern_speed(config, "horizontal"))  # level patterns: their own altitude
    limit = flight_envelope(config.vehicle, config.controller).airspeed_m_s
    assert result.envelope.airspeed_m_s == limit
    assert torch.equal(result.episodes["envelope", "margin"], limit - demand["demand"])
    assert torch.equal(result.episodes["envelope", "sustained_margin"], limit - demand["sustained"])
    rows = episode_rows(result.episodes)
    assert [r["episode"] for r in rows] == [0, 1] and rows[0]["trajectory"] == trajectory_name(scenarios["traj_id"][0])
    assert {"wind_speed_ref_m_s", "turb_intensity", "shear_alpha", "altitude_m"} <= set(rows[0])
    assert set(rows[0]["policies"]) == set(result.metrics) and set(rows[0]["pd"]) == {"rmse_xy", "rmse_z", "rmse", "crashed"}


def test_vertical_sweep_margins_at_the_climb_top():
    # no flight: the whole vertical validation sweep; a climb's wind is taken at its top (600 m),
    # which is each scenario's altitude_m, so envelope.py on the scenarios themselves is the reference
    config = policy_env_config(load_policy(VERTICAL)[1])
    scenarios = validation_scenarios("vertical")
    envelope = flight_envelope(config.vehicle, config.controller)
    table = episode_envelope(scenarios, config, pattern_speed(config, "vertical"), envelope)
    demand = airspeed_demand(scenarios, config, pattern_speed(config, "vertical"))
    assert torch.equal(table["margin"], envelope.airspeed_m_s - demand["demand"])
    beyond = table["margin"] < 0
    assert beyond.any() and (scenarios["wind_speed_ref_m_s"][beyond] == 10.0).all()  # only the strongest wind
    # a quick climb stops at 10 m: its demand is taken there, not at the sweep's 600 m
    quick = PPO_QUICK["vertical"].config(config)
    assert (flight_altitude(scenarios, quick) == quick.trajectories.vertical_top_m).all()


def test_envelope_split_counts_and_improvements():
    n = 3
    def flight(rmse: list[float], crashed: list[bool]) -> TensorDict:
        return TensorDict(rmse_xy=torch.tensor(rmse), rmse_z=torch.ones(n), rmse=torch.tensor(rmse),
                          crashed=torch.tensor(crashed), batch_size=[n])

    table = TensorDict(envelope=TensorDict(margin=torch.tensor([1.0, -0.5, 0.0]), batch_size=[n]),
                       pd=flight([1.0, 4.0, 3.0], [False, False, False]),
                       policies=TensorDict(p=flight([0.5, 5.0, 3.0], [False, True, False]), batch_size=[n]), batch_size=[n])
    split = envelope_split(table)
    within, beyond = split["within"], split["beyond"]
    assert within["episodes"] == 2 and beyond["episodes"] == 1  # a margin of 0 is within
    assert within["policies"]["p"]["improvement_rmse_pct"] == pytest.approx(100 * (1 - 3.5 / 4.0))
    assert (within["policies"]["p"]["wins"], beyond["policies"]["p"]["wins"]) == (1, 0)
    assert (within["policies"]["p"]["crashed"], beyond["policies"]["p"]["crashed"], beyond["pd_crashed"]) == (0, 1, 0)
    empty = envelope_split(table[:1])["beyond"]["policies"]["p"]
    assert empty["episodes"] == 0 and empty["improvement_rmse_xy_pct"] is None  # no mean, no NaN in the JSON


@pytest.mark.parametrize("paths,words", [
    ([AWARE, VERTICAL], ["regime='horizontal'", "regime='vertical'", "policy_horizontal.pt", "policy_vertical.pt"]),
    ([AWARE, AWARE], ["policy_horizontal.pt", "more than once"]),
    ([], ["policy_paths", "one or more"]),
], ids=["mixed regimes", "twice", "none"])
def test_policies_that_cannot_share_pd_are_refused(paths, words):
    with pytest.raises(ValueError) as info:
        validate_policies(paths, episodes=2, quick=True, compile_step=False)
    for word in words:
        assert word in str(info.value), f"{word!r} not in {str(info.value)!r}"


def test_recipe_writes_rows_and_prints_the_envelope_split(both, tmp_path, monkeypatch, capsys):
    path = ROOT / "recipes" / "validate_policy.py"
    spec = importlib.util.spec_from_file_location("validate_policy_recipe_episodes", path)
    recipe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(recipe)
    result, _ = both
    monkeypatch.setattr(recipe, "validate_policies", lambda *a, **k: copy.deepcopy(result))  # the flights above
    out = tmp_path / "val.json"
    monkeypatch.setattr(sys, "argv", [str(path), "--policy", str(AWARE), str(BLIND), "--monitor", "--episodes", "2",
                                      "--quick", "--eager", "--no-progress", "--out", str(out)])
    recipe.main()
    saved = json.loads(out.read_text())
    assert list(saved["policies"]) == list(result.metrics) and "metrics" not in saved  # several: by label only
    assert saved["policies"]["policy_horizontal"]["path"].endswith("policy_horizontal.pt")
    assert len(saved["episode_rows"]) == 2 and saved["episode_rows"][0]["envelope"]["margin"] > 0
    assert saved["by_envelope"]["within"]["episodes"] == 2 and saved["envelope"]["gust_sigmas"] == 2.0
    printed = capsys.readouterr().out
    assert "policy_horizontal_trained_blind: 2 episodes" in printed and "within" in printed and "beyond" in printed
