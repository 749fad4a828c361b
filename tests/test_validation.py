"""The validation layer: each bad input a user can hand the library fails early, and the message
names the field (and the allowed range or names)."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
import torch

from quadwind_trl.config import EnvConfig, TurbulenceConfig, VehicleConfig
from quadwind_trl.envs import QuadWindEnv, make_scenarios
from quadwind_trl.envs.scenarios import RegimeRanges
from quadwind_trl.envs.trajectories import trajectory_names
from quadwind_trl.estimator import EstimatorBundle
from quadwind_trl.rl.policy import load_policy

CHECKPOINTS = Path(__file__).resolve().parent.parent / "quadwind_trl" / "checkpoints"
NAN = float("nan")

# (case, callable, exception type, words the message must contain)
BAD_SCENARIOS = [
    ("negative wind speed", lambda: make_scenarios(4, wind_speed_ref_m_s=-3.0), ValueError, ["wind_speed_ref_m_s", "=-3 ", "[0, 40]"]),
    ("NaN wind speed", lambda: make_scenarios(4, wind_speed_ref_m_s=NAN), ValueError, ["wind_speed_ref_m_s", "nan", "finite"]),
    ("negative intensity", lambda: make_scenarios(4, turb_intensity=-0.1), ValueError, ["turb_intensity", "[0, 1]"]),
    ("intensity 1.7", lambda: make_scenarios(4, turb_intensity=1.7), ValueError, ["turb_intensity", "1.7", "[0, 1]"]),
    ("altitude -40 m", lambda: make_scenarios(4, altitude_m=-40.0), ValueError, ["altitude_m", "=-40 ", "[0, 3000]"]),
    ("length scale -80 m", lambda: make_scenarios(4, turb_length_scale_m=-80.0), ValueError, ["turb_length_scale_m", "=-80 "]),
    ("unknown trajectory", lambda: make_scenarios(4, traj_id="figure9"), ValueError, ["traj_id", "figure9", *trajectory_names()]),
    ("trajectory id 42", lambda: make_scenarios(4, traj_id=42), ValueError, ["traj_id", "42", "lawnmower_h"]),
    ("stability 5", lambda: make_scenarios(4, stability=5), ValueError, ["stability", "5", "neutral", "convective"]),
    ("wrong-length seed list", lambda: make_scenarios(4, turb_seed=[1, 2, 3]), ValueError, ["turb_seed", "(3,)", "4 values"]),
    ("wrong-length altitude list", lambda: make_scenarios(4, altitude_m=[100.0, 200.0]), ValueError, ["altitude_m", "(2,)", "4 values"]),
    ("fractional seed", lambda: make_scenarios(2, sensor_seed=[1.5, 2.0]), ValueError, ["sensor_seed", "integers"]),
    ("string wind speed", lambda: make_scenarios(2, wind_speed_ref_m_s="fast"), TypeError, ["wind_speed_ref_m_s", "fast"]),
]


@pytest.fixture(scope="module")
def env4() -> QuadWindEnv:
    env = QuadWindEnv(batch_size=[4])
    env.reset()
    return env


def _step_with(env: QuadWindEnv, action: torch.Tensor):
    td = env.reset()
    td["action"] = action
    return env.step(td)


def _bad_reset_scenario(env: QuadWindEnv):
    sc = make_scenarios(4)
    sc["turb_intensity"][2] = 1.7  # a spec edited by hand after make_scenarios
    return env.reset(scenario=sc)


BAD_CONFIGS = [
    ("negative mass", lambda: EnvConfig(vehicle=VehicleConfig(mass_kg=-1.0)).validate(), ValueError, ["mass_kg", "-1.0"]),
    ("NaN turbulence modes", lambda: EnvConfig(turbulence=replace(TurbulenceConfig(), num_modes=NAN)).validate(),
     TypeError, ["num_modes", "nan"]),
    ("unknown feedback", lambda: EnvConfig(controller=replace(EnvConfig().controller, feedback="gps")).validate(),
     ValueError, ["feedback", "gps", "truth"]),
    ("wrong-length gains", lambda: EnvConfig(controller=replace(EnvConfig().controller, kp_pos=(5.0, 5.0))).validate(),
     ValueError, ["kp_pos", "3 values"]),
    ("reversed design range", lambda: RegimeRanges(intensity=(0.3, 0.1)), ValueError, ["intensity", "(0.3, 0.1)"]),
]


@pytest.mark.parametrize("case,call,exc,words", BAD_SCENARIOS + BAD_CONFIGS, ids=[c[0] for c in BAD_SCENARIOS + BAD_CONFIGS])
def test_bad_input_names_the_field(case, call, exc, words):
    with pytest.raises(exc) as info:
        call()
    for word in words:
        assert word in str(info.value), f"{case}: {word!r} not in {str(info.value)!r}"


@pytest.mark.parametrize(
    "case,call,words",
    [
        ("action (4, 3)", lambda env: _step_with(env, torch.zeros(4, 3)), ["action", "(4, 3)", "(4, 4)"]),
        ("action (4,)", lambda env: _step_with(env, torch.zeros(4)), ["action", "(4,)", "(4, 4)"]),
        ("scenario edited to intensity 1.7", _bad_reset_scenario, ["turb_intensity", "row 2", "[0, 1]"]),
        ("scenario of another batch", lambda env: env.reset(scenario=make_scenarios(3)), ["scenario", "[3]", "[4]"]),
    ],
    ids=lambda c: c if isinstance(c, str) else "",
)
def test_bad_env_input_names_the_field(env4, case, call, words):
    with pytest.raises(ValueError) as info:
        call(env4)
    for word in words:
        assert word in str(info.value), f"{case}: {word!r} not in {str(info.value)!r}"


def test_fly_checks_scenarios_before_flying(env4):
    from quadwind_trl.envs.runner import fly

    sc = make_scenarios(4)
    sc["traj_id"][0] = 42
    with pytest.raises(ValueError, match="traj_id=42"):
        fly(env4, sc)


@pytest.mark.parametrize(
    "loader,path,words",
    [
        (load_policy, CHECKPOINTS / "estimator_horizontal.pt", ["is a wind-estimator bundle", "not a PPO policy"]),
        (EstimatorBundle.load, CHECKPOINTS / "policy_horizontal.pt", ["is a PPO policy", "not a wind-estimator bundle"]),
        (load_policy, CHECKPOINTS / "policy_horizontal.json", ["not a quadwind_trl checkpoint"]),
    ],
    ids=["load_policy on an estimator", "EstimatorBundle.load on a policy", "load_policy on a JSON file"],
)
def test_loading_the_wrong_kind_of_checkpoint_says_what_it_is(loader, path, words):
    with pytest.raises(ValueError) as info:
        loader(path)
    for word in words:
        assert word in str(info.value)


def test_checkpoints_carry_a_kind_and_old_ones_still_load(tmp_path):
    from quadwind_trl.estimator import untrained_estimator

    # files saved before "kind" existed: their kind is inferred from their entries
    for name, load in (("policy_horizontal", load_policy), ("estimator_horizontal", EstimatorBundle.load)):
        payload = torch.load(CHECKPOINTS / f"{name}.pt", weights_only=True)
        assert payload.pop("kind") in name
        torch.save(payload, tmp_path / f"{name}.pt")
        load(tmp_path / f"{name}.pt")
    bundle = untrained_estimator("horizontal")
    bundle.save(tmp_path / "est.pt")
    assert torch.load(tmp_path / "est.pt", weights_only=True)["kind"] == "estimator"
    with pytest.raises(ValueError, match="is a wind-estimator bundle"):
        load_policy(tmp_path / "est.pt")


def test_valid_inputs_pass_unchanged():
    sc = make_scenarios(2, traj_id=["lawnmower_h", "figure8_h"], altitude_m=100.0, wind_speed_ref_m_s=8.0,
                        turb_intensity=0.15, turb_seed=[1, 2], sensor_seed=[3, 4], start_step=-1)
    assert sc["traj_id"].tolist() == [4, 2]  # the built-in ids never change: datasets and results hold them
    assert sc["turb_seed"].dtype == torch.int64 and sc["altitude_m"].dtype == torch.float32
    EnvConfig().validate()
