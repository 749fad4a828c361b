"""Error paths at the library's boundaries that no other test reaches: each bad input fails with
the right exception type, and the message names the field (or key) and what is allowed. Fast:
no flight, at most one small env."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
import torch

from quadwind_trl.config import (
    LEGACY_SENSORS,
    EnvConfig,
    MonitorConfig,
    SensorConfig,
    config_from_dict,
    with_monitor,
    with_sensing,
    with_sensor_preset,
)
from quadwind_trl.envs import QuadWindEnv, ScenarioSampler, make_scenarios, parallel_env, trajectory_name
from quadwind_trl.envs.scenarios import RegimeRanges, validate_scenarios
from quadwind_trl.estimator import load_estimator
from quadwind_trl.gym import QuadWindVectorEnv
from quadwind_trl.keys import observation_index
from quadwind_trl.regimes import regime_config
from quadwind_trl.rl.config import Curriculum, PPOConfig
from quadwind_trl.rl.policy import load_policy
from quadwind_trl.validation import check_action, load_checkpoint

CHECKPOINTS = Path(__file__).resolve().parent.parent / "quadwind_trl" / "checkpoints"
E = EnvConfig()


def _raises(call, exc, words):
    with pytest.raises(exc) as info:
        call()
    assert type(info.value) is exc, f"{type(info.value).__name__}: {info.value}"
    for word in words:
        assert word in str(info.value), f"{word!r} not in {str(info.value)!r}"


def _env(**parts) -> EnvConfig:
    """``EnvConfig`` with fields of its parts replaced: ``_env(vehicle={"mass_kg": 1.0})``."""
    return replace(E, **{part: replace(getattr(E, part), **changes) for part, changes in parts.items()})


def _monitor(**changes) -> EnvConfig:
    return with_monitor(E, replace(MonitorConfig(), **changes))


def _sensor(**changes) -> EnvConfig:
    return _env(sensors={"gyro": replace(E.sensors.gyro, **changes)})


# (case, callable, exception type, words the message must contain)
BAD_CONFIGS = [
    ("rotor_aero", lambda: _env(vehicle={"rotor_aero": "blade"}).validate(), ValueError, ["rotor_aero", "'blade'", "'momentum'"]),
    ("rotor_aero, sub-config alone", lambda: replace(E.vehicle, rotor_aero="blade").validate(), ValueError,
     ["VehicleConfig.rotor_aero", "'static'"]),
    ("height_reference", lambda: _env(navigation={"height_reference": "gps"}).validate(), ValueError,
     ["height_reference", "'gps'", "'baro'", "'gnss'"]),
    ("cap_applies_to", lambda: _env(wind={"cap_applies_to": "gust"}).validate(), ValueError, ["cap_applies_to", "'mean'", "'total'"]),
    ("turbulence layout", lambda: _env(turbulence={"layout": "grid"}).validate(), ValueError, ["layout", "'full'", "'paper_grid'"]),
    ("anisotropy", lambda: _env(turbulence={"anisotropy": "none"}).validate(), ValueError, ["anisotropy", "'stretch'"]),
    ("thrust beyond the rotors", lambda: _env(vehicle={"collective_thrust_max_hover": 9.0}).validate(), ValueError,
     ["collective_thrust_max_hover", "x hover"]),
    ("arm length 0", lambda: _env(vehicle={"arm_length_m": 0.0}).validate(), ValueError, ["arm_length_m=0.0", "[0.01, 5]"]),
    ("mass as a string", lambda: _env(vehicle={"mass_kg": "2.5"}).validate(), TypeError, ["mass_kg", "'2.5'", "a number"]),
    ("inertia as a list", lambda: _env(vehicle={"inertia_kg_m2": [0.1, 0.1, 0.2]}).validate(), TypeError, ["inertia_kg_m2", "a tuple"]),
    ("negative drag area", lambda: _env(vehicle={"drag_area_xy_m2": -0.1}).validate(), ValueError, ["drag_area_xy_m2", ">= 0"]),
    ("fractional cube points", lambda: _env(turbulence={"cube_points": 32.5}).validate(), TypeError, ["cube_points", "an integer"]),
    ("enabled as 1", lambda: _env(sensors={"enabled": 1}).validate(), TypeError, ["enabled", "True or False"]),
    ("navigation gain 2", lambda: _env(navigation={"baro_gain": 2.0}).validate(), ValueError, ["baro_gain=2.0", "[0.0, 1.0]"]),
    ("zero slew limit", lambda: _env(residual={"slew_limit_per_step": (0.0, 0.1, 0.1, 0.1)}).validate(), ValueError,
     ["slew_limit_per_step=(0.0,", "> 0"]),
    ("smoothing 1", lambda: _env(residual={"smoothing": 1.0}).validate(), ValueError, ["smoothing=1.0", "[0.0, 0.999]"]),
    ("hold not dividing the log", lambda: _env(timing={"hold_control_steps": 3}).validate(), ValueError,
     ["hold_control_steps=3", "log_every_control_steps=10"]),
    ("physics dt 0", lambda: _env(timing={"physics_dt_s": 0.0}).validate(), ValueError, ["physics_dt_s=0.0", "[1e-05, 0.1]"]),
    ("reversed kappa range", lambda: _env(turbulence={"kappa_range": (5.0, 1.0)}).validate(), ValueError,
     ["kappa_range=(5.0, 1.0)", "increasing"]),
    ("one stability pair", lambda: _env(turbulence={"stability_ratios": ((0.8, 0.5),)}).validate(), ValueError,
     ["stability_ratios", "three", "neutral, stable, convective"]),
    ("sensor rate 0", lambda: _sensor(rate_hz=0.0).validate(), ValueError, ["gyro", "rate_hz=0.0", "[0.01, 10000.0]"]),
    ("gyro and accel rates differ", lambda: _sensor(rate_hz=500.0).validate(), ValueError, ["gyro.rate_hz=500.0", "accel.rate_hz", "equal"]),
    ("bias correlation time 0", lambda: _sensor(bias_corr_time_s=0.0).validate(), ValueError, ["bias_corr_time_s=0.0", "[0.001, inf]"]),
    ("cruise speed 50", lambda: _env(trajectories={"cruise_speed_m_s": 50.0}).validate(), ValueError, ["cruise_speed_m_s=50.0", "[0.5, 25.0]"]),
    ("sensor preset", lambda: with_sensor_preset(E, "gps"), ValueError, ["'gps'", "'rtk'", "'legacy_walk'"]),
    ("sensing", lambda: with_sensing(E, "perfect"), ValueError, ["sensing='perfect'", "'no_bias'", "'true_state'"]),
    ("monitor tilt margin 60", lambda: _monitor(tilt_margin_deg=60.0).validate(), ValueError,
     ["MonitorConfig.tilt_margin_deg=60.0", "[0.0, 45.0]"]),
    ("monitor thrust fraction at hover", lambda: _monitor(thrust_fraction=0.4).validate(), ValueError,
     ["MonitorConfig.thrust_fraction=0.4", "[0.5, 1.0]"]),
    ("monitor height drop 0", lambda: _monitor(height_below_ref_m=0.0).validate(), ValueError,
     ["MonitorConfig.height_below_ref_m=0.0", "[0.5, 100.0]"]),
    ("monitor height as a string", lambda: _monitor(height_below_ref_m="5").validate(), TypeError,
     ["residual.monitor.height_below_ref_m='5'", "a number"]),
    ("monitor negative hold", lambda: _monitor(hold_s=-1.0).validate(), ValueError, ["monitor.hold_s=-1.0", ">= 0"]),
    ("monitor hold of minutes", lambda: _monitor(hold_s=120.0).validate(), ValueError, ["MonitorConfig.hold_s=120.0", "[0.0, 60.0]"]),
    ("monitor as a dict", lambda: _env(residual={"monitor": {"hold_s": 1.0}}).validate(), TypeError,
     ["ResidualConfig.monitor={'hold_s': 1.0}", "MonitorConfig or None"]),
    ("saved monitor, unknown field", lambda: config_from_dict(EnvConfig, {"residual": {"monitor": {"hold": 1.0}}}), KeyError,
     ["MonitorConfig has no fields ['hold']", "hold_s"]),
    ("saved config, unknown field", lambda: config_from_dict(EnvConfig, {"vehicle": {"mass": 2.0}}), KeyError,
     ["VehicleConfig", "'mass'", "'mass_kg'"]),
    ("saved walk sensors, other noise", lambda: config_from_dict(SensorConfig, {
        name: {"noise_std": 2 * ch.noise_std, "bias_walk_std_per_sqrt_s": ch.bias_drive_std_per_sqrt_s}
        for name, ch in LEGACY_SENSORS.channels().items()}), ValueError, ["SensorConfig.gps_pos", "legacy_walk", "noise_std="]),
    ("PPO minibatch 0", lambda: PPOConfig(minibatch=0).validate(), ValueError, ["minibatch=0", ">= 1"]),
    ("PPO minibatch not dividing", lambda: PPOConfig(minibatch=7).validate(), ValueError, ["minibatch=7", "multiple"]),
    ("PPO collect workers 0", lambda: PPOConfig(collect_workers=0).validate(), ValueError, ["collect_workers=0", ">= 1"]),
    ("PPO collect workers not dividing", lambda: PPOConfig(collect_workers=3).validate(), ValueError,
     ["collect_workers=3", "must divide num_envs=64"]),
    ("PPO collector", lambda: PPOConfig(collector="dask").validate(), ValueError, ["collector='dask'", "'ray'"]),
    ("PPO Ray collectors 0", lambda: PPOConfig(collector="ray", num_collectors=0).validate(), ValueError,
     ["num_collectors=0", ">= 1"]),
    ("PPO Ray collectors not dividing", lambda: PPOConfig(collector="ray", num_collectors=3).validate(), ValueError,
     ["num_collectors=3 (--num-collectors)", "must divide num_envs=64"]),
    ("PPO Ray collectors, local collector", lambda: PPOConfig(num_collectors=2).validate(), ValueError,
     ["num_collectors=2", "only with collector='ray' (--collector ray)"]),
    ("PPO Ray address, local collector", lambda: PPOConfig(ray_address="auto").validate(), ValueError,
     ["ray_address='auto'", "only with collector='ray'"]),
    ("PPO Ray and local workers", lambda: PPOConfig(collector="ray", collect_workers=2).validate(), ValueError,
     ["collect_workers=2", "Ray actors (--num-collectors)"]),
    ("PPO malformed Ray address", lambda: PPOConfig(collector="ray", ray_address="head-node").validate(), ValueError,
     ["--address 'head-node'", "'auto' or HOST:PORT"]),
    ("PPO activation", lambda: PPOConfig(activation="gelu").validate(), ValueError, ["activation='gelu'", "'tanh'"]),
    ("PPO lr schedule", lambda: PPOConfig(lr_schedule="cosine").validate(), ValueError, ["lr_schedule='cosine'", "'linear'"]),
    ("PPO reward scaling", lambda: PPOConfig(reward_scaling="popart").validate(), ValueError,
     ["reward_scaling='popart'", "'return_std'"]),
    ("PPO lr 0", lambda: PPOConfig(lr=0.0).validate(), ValueError, ["lr=0.0", "> 0"]),
    ("PPO init scale 0", lambda: PPOConfig(init_scale=0.0).validate(), ValueError, ["init_scale=0.0", "> 0"]),
    ("curriculum, starts per stage", lambda: Curriculum(stages=(("hover",), ("racetrack_h",)), starts=(0.0,)), ValueError,
     ["2 stages", "1 starts", "one start fraction per stage"]),
]

BAD_DESIGNS = [
    ("string bound", lambda: RegimeRanges(intensity=("low", 0.3)), TypeError, ["RegimeRanges.intensity", "'low'", "pair of numbers"]),
    ("not a pair", lambda: RegimeRanges(shear_alpha=0.2), ValueError, ["RegimeRanges.shear_alpha=0.2", "(low, high)"]),
    ("beyond the scenario range", lambda: RegimeRanges(wind_speed_m_s=(1.0, 50.0)), ValueError, ["wind_speed_m_s", "[0, 40]"]),
    ("negative top altitude", lambda: RegimeRanges(top_altitude_m=-1.0), ValueError, ["top_altitude_m=-1.0", "> 0"]),
    ("string ceiling", lambda: RegimeRanges(wind_ceiling_m_s="20"), TypeError, ["wind_ceiling_m_s='20'", "a number"]),
]


def _edited(field: str, value: torch.Tensor):
    sc = make_scenarios(2)
    sc[field] = value
    return validate_scenarios(sc)


BAD_SCENARIOS = [
    ("batch 0", lambda: make_scenarios(0), ValueError, ["batch=0", "positive integer"]),
    ("batch 1.5", lambda: make_scenarios(1.5), TypeError, ["batch=1.5", "positive integer"]),
    ("boolean wind speed", lambda: make_scenarios(2, wind_speed_ref_m_s=True), TypeError, ["wind_speed_ref_m_s=True", "real number"]),
    ("nested list", lambda: make_scenarios(2, shear_alpha=[[0.1, 0.2]]), ValueError, ["shear_alpha", "(1, 2)", "2 values"]),
    ("negative seed", lambda: make_scenarios(2, turb_seed=-1), ValueError, ["turb_seed=-1", "row 0", "[0, 4.61169e+18]"]),
    ("start step -2", lambda: make_scenarios(2, start_step=-2), ValueError, ["start_step=-2", "[-1,", "starts at the pattern"]),
    ("unknown name in a list", lambda: make_scenarios(2, traj_id=["hover", "helix"]), ValueError, ["'helix'", "hover", "figure8_3d"]),
    ("field missing", lambda: validate_scenarios(make_scenarios(2).exclude("sensor_seed")), ValueError,
     ["missing fields ['sensor_seed']", "make_scenarios"]),
    ("float seeds", lambda: _edited("turb_seed", torch.zeros(2)), TypeError, ["turb_seed", "torch.float32", "torch.int64"]),
    ("trajectory id -1", lambda: _edited("traj_id", torch.tensor([0, -1])), ValueError, ["traj_id=-1", "row 1", "0 loiter_circle_h", "9 hover"]),
    ("a 2-D batch", lambda: validate_scenarios(make_scenarios(2).unsqueeze(0)), ValueError, ["batch [N]", "[1, 2]"]),
    ("trajectory name of a name", lambda: trajectory_name("hover"), TypeError, ["traj_id='hover'", "integer id", "0-9"]),
    ("sampler start", lambda: ScenarioSampler(start="air"), ValueError, ["start='air'", "'ground'", "'pattern'"]),
    ("sampler trajectories as one string", lambda: ScenarioSampler(trajectories="hover"), TypeError,
     ["trajectories='hover'", "sequence of names", "('hover',)"]),
    ("env batch [0]", lambda: QuadWindEnv(batch_size=[0]), ValueError, ["batch_size=[0]", "N >= 1"]),
    ("env batch [2, 2]", lambda: QuadWindEnv(batch_size=[2, 2]), ValueError, ["batch_size=[2, 2]", "[N]"]),
    ("env first row -1", lambda: QuadWindEnv(first_row=-1), ValueError, ["first_row=-1", ">= 0"]),
    ("parallel workers 0", lambda: parallel_env(0, 4), ValueError, ["num_workers=0", ">= 1"]),
    ("parallel rows uneven", lambda: parallel_env(3, 4), ValueError, ["num_envs=4", "multiple of num_workers=3"]),
    ("parallel threads 0", lambda: parallel_env(2, 4, threads_per_worker=0), ValueError, ["threads_per_worker=0", ">= 1"]),
    ("missing action", lambda: check_action(None, 2, 4), ValueError, ["'action'", "(2, 4)"]),
    ("observation channel", lambda: observation_index("wind_x"), ValueError, ["'wind_x'", "channels"]),
    ("regime", lambda: regime_config("diagonal"), ValueError, ["regime='diagonal'", "'horizontal'", "'vertical'"]),
    ("estimator regime", lambda: load_estimator("diagonal"), ValueError, ["regime='diagonal'", "'horizontal'", "'vertical'"]),
    ("gym regime, truth wind", lambda: QuadWindVectorEnv("diagonal", 2, wind_input="truth"), ValueError,
     ["regime='diagonal'", "'horizontal'", "'vertical'"]),
]


@pytest.mark.parametrize("case,call,exc,words", BAD_CONFIGS + BAD_DESIGNS + BAD_SCENARIOS,
                         ids=[c[0] for c in BAD_CONFIGS + BAD_DESIGNS + BAD_SCENARIOS])
def test_bad_input_names_the_field_and_what_is_allowed(case, call, exc, words):
    _raises(call, exc, words)


@pytest.mark.parametrize("key", ["rotor_speed", ("body", "rotor_speed"), ("nowhere", "at_all")])
def test_sim_state_of_an_unknown_key_lists_the_entries(key):
    env = QuadWindEnv(batch_size=[1])
    env.reset()
    _raises(lambda: env.sim_state(key), KeyError, [repr(key), "('body', 'rotor')", "'pattern_start'"])
    assert torch.equal(env.sim_state(("body", "rotor")), env.state["body", "rotor"])


def _saved(tmp_path: Path, name: str, payload) -> Path:
    torch.save(payload, tmp_path / name)
    return tmp_path / name


@pytest.mark.parametrize(
    "case,load,exc,words",
    [
        ("no file", lambda d: load_checkpoint(d / "absent.pt", "policy"), FileNotFoundError, ["absent.pt"]),
        ("a list", lambda d: load_checkpoint(_saved(d, "list.pt", [1, 2]), "policy"), ValueError,
         ["list.pt", "not a quadwind_trl checkpoint", "holds a list"]),
        ("a dict of neither kind", lambda d: load_checkpoint(_saved(d, "other.pt", {"weights": 1}), "estimator"), ValueError,
         ["other.pt", "not a quadwind_trl checkpoint", "no policy or estimator entries"]),
        ("no estimator file", lambda d: load_estimator("horizontal", d / "absent.pt"), FileNotFoundError,
         ["absent.pt", "--untrained-estimator"]),
        ("another observation layout", lambda d: load_policy(_saved(d, "policy.pt", {
            **torch.load(CHECKPOINTS / "policy_horizontal.pt", weights_only=True), "observation_channels": ["a", "b"]})),
         ValueError, ["policy.pt", "another observation layout", "['a', 'b']", "observation_channels (23 channels"]),
    ],
    ids=lambda c: c if isinstance(c, str) else "",
)
def test_bad_checkpoint_files_say_what_is_wrong(tmp_path, case, load, exc, words):
    _raises(lambda: load(tmp_path), exc, words)
