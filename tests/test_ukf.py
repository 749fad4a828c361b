"""The model-based wind estimator (``quadwind_trl.estimator.ukf``): closed forms on synthetic
windows made from the simulator's own drag law, the model-error bias, the WindEstimator protocol
inside ``WindEstimate``, bad settings, and a short flight in the real simulator."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from quadwind_trl.config import GRAVITY_M_S2, EnvConfig, TrajectoryConfig, TurbulenceConfig
from quadwind_trl.envs import QuadWindEnv, make_scenarios
from quadwind_trl.envs.runner import fly
from quadwind_trl.envs.vehicle import drag_force_body
from quadwind_trl.estimator import WindEstimator
from quadwind_trl.estimator.features import RAW_RECORD_KEYS, make_extractor, raw_record_template, rotation_from_euler
from quadwind_trl.estimator.ukf import UKF_INPUT_CHANNELS, UKFConfig, WindUKF, heading_from_aero
from quadwind_trl.keys import MEAS_KEY

EXACT = UKFConfig(drag_scale=1.0, mass_scale=1.0)


def synthetic_windows(wind_ne: tuple[float, float], vel_enu: torch.Tensor, yaw: torch.Tensor, roll: torch.Tensor,
                      pitch: torch.Tensor, config: EnvConfig) -> torch.Tensor:
    """Noise-free horizontal feature windows ``[n, T, C]`` of a vehicle with ground velocity
    ``vel_enu`` ``[n, T, 3]`` and attitude ``[n, T]`` in a steady ``wind_ne``: the accelerometer
    reads the simulator's drag law plus a thrust along body z (the hover thrust, tilt-corrected)."""
    veh = config.vehicle
    n, t_len = yaw.shape
    r = rotation_from_euler(roll, pitch, yaw)
    air = vel_enu - torch.tensor([wind_ne[1], wind_ne[0], 0.0])
    air_body = torch.stack([sum(r[j][i] * air[..., j] for j in range(3)) for i in range(3)], -1)  # R^T air
    half_rho_cda = 0.5 * veh.air_density_kg_m3 * torch.tensor([veh.drag_area_xy_m2, veh.drag_area_xy_m2, veh.drag_area_z_m2])
    thrust = veh.mass_kg * GRAVITY_M_S2 / (torch.cos(roll) * torch.cos(pitch))
    force = drag_force_body(air_body, half_rho_cda) + torch.nn.functional.pad(thrust[..., None], (2, 0))
    rec = raw_record_template(n, t_len).clone()
    meas = rec[MEAS_KEY]
    meas["gps_vel"] = vel_enu
    meas["attitude"] = torch.stack((roll, pitch, yaw), -1)
    meas["accel"] = force / veh.mass_kg
    meas["baro_alt"] = torch.full((n, t_len, 1), 50.0)
    rec["cmd_wrench"] = torch.nn.functional.pad(thrust[..., None], (0, 3))
    return make_extractor("horizontal", config).scan(rec)


def level_flight(wind_ne, n: int = 3, t_len: int = 60, speed: float = 6.0):
    """Rows: hover; a straight leg at ``speed`` heading north-east; a steady turn at ``speed``
    (the heading follows the track), all level (roll = pitch = 0)."""
    t = torch.arange(t_len) * 0.1
    heading = torch.stack((torch.zeros_like(t), torch.full_like(t, math.pi / 4), 0.3 * t))[:n]  # from east, CCW
    ground_speed = torch.tensor([0.0, speed, speed])[:n, None]
    vel = torch.stack((ground_speed * torch.cos(heading), ground_speed * torch.sin(heading), torch.zeros_like(heading)), -1)
    zero = torch.zeros_like(heading)
    return synthetic_windows(wind_ne, vel, heading, zero, zero, EnvConfig()), vel


@pytest.mark.parametrize("wind_ne", [(5.0, -3.0), (-8.0, 2.0), (12.0, 5.0)])
def test_converges_to_a_steady_wind_with_the_exact_model(wind_ne):
    """Closed form: no noise, no turbulence, exact airframe, from zero wind. In hover, on a
    straight leg and in a turn the filtered wind is within 0.05 m/s of the truth from 4.5 s on
    (slowest: hover with 2 m/s along one body axis, where drag is 0.07 m/s^2, about the
    accelerometer's noise) and within 0.01 m/s at the window's end; the window estimate (its last
    3 s averaged) is within 0.05 m/s."""
    windows, _ = level_flight(wind_ne)
    est = WindUKF(EXACT)
    track, _ = est.track(windows)
    err = (track - torch.tensor(wind_ne)).norm(dim=-1)  # [n, T]
    assert err[:, 45:].max() < 0.05 and err[:, -1].max() < 0.01, err[:, ::5]
    assert (est.predict(windows) - torch.tensor(wind_ne)).norm(dim=-1).max() < 0.05


def test_tilted_flight_converges_too():
    """Roll and pitch map the vertical ground speed into body x and y, and the heading comes back
    from the aero channels exactly: with 6-9 m/s airspeed the filtered wind is within 0.05 m/s
    from 2 s on."""
    t_len = 60
    t = torch.arange(t_len) * 0.1
    roll = (0.15 * torch.sin(0.7 * t))[None]
    pitch = (-0.1 + 0.05 * torch.cos(0.5 * t))[None]
    yaw = (1.0 + 0.2 * t)[None]
    vel = torch.stack((4.0 * torch.cos(0.3 * t), 3.0 * torch.ones_like(t), 1.5 * torch.sin(t)), -1)[None]
    wind = (-4.0, 6.0)
    windows = synthetic_windows(wind, vel, yaw, roll, pitch, EnvConfig())
    est = WindUKF(EXACT)
    col = {name: windows[..., est.channels.index(name)] for name in UKF_INPUT_CHANNELS}
    sf_b = (col["sf_bx"], col["sf_by"], col["sf_bz"])
    cos_yaw, sin_yaw = heading_from_aero(roll, pitch, sf_b, col["u_T"], col["aero_E"], col["aero_N"], est.feature_mass_kg)
    assert torch.allclose(cos_yaw, torch.cos(yaw), atol=1e-4) and torch.allclose(sin_yaw, torch.sin(yaw), atol=1e-4)
    track, _ = est.track(windows)
    assert (track[0, 20:] - torch.tensor(wind)).norm(dim=-1).max() < 0.05


def test_model_error_bias_matches_the_closed_form():
    """With the filter's k/m = drag_scale / mass_scale times the truth, each body-axis airspeed is
    inferred sqrt(mass_scale / drag_scale) times the true one: the wind error is
    (1 - sqrt(mass_scale / drag_scale)) (v_ground - w), along the air-relative velocity."""
    cfg = UKFConfig()  # the stated model error: drag +15 %, mass -5 %
    shrink = math.sqrt(cfg.mass_scale / cfg.drag_scale)
    wind = torch.tensor((5.0, -3.0))  # north, east
    windows, vel = level_flight(tuple(wind.tolist()), n=2)
    v_ne = torch.stack((vel[:, -1, 1], vel[:, -1, 0]), -1)  # ground velocity, (north, east)
    expected = wind + (1.0 - shrink) * (v_ne - wind)
    got = WindUKF(cfg).predict(windows)
    assert (got - expected).norm(dim=-1).max() < 0.03, (got, expected)
    # in hover the speed is 9.1 % low and the direction right
    assert abs(got[0].norm() / wind.norm() - shrink) < 0.005


def test_bad_settings_are_refused_naming_the_field():
    for field, value in (("drag_scale", 0.0), ("mass_scale", 10.0), ("accel_noise_m_s2", 0.0),
                         ("initial_wind_std_m_s", -1.0), ("window", 0), ("average_last_s", -0.1)):
        with pytest.raises(ValueError, match=f"UKFConfig.{field}=.*allowed range"):
            UKFConfig(**{field: value})
    with pytest.raises(ValueError, match="expected \\[B, T, 48\\]"):
        WindUKF().predict(torch.zeros(2, 60, 22))


def _steady_wind_config(**turbulence) -> EnvConfig:
    # a 12 s hover: the last 6 s window starts after the PD has settled, and the file stays < 30 s
    cfg = EnvConfig(trajectories=TrajectoryConfig(hover_duration_s=12.0, horizontal_duration_s=4.0))
    return replace(cfg, turbulence=TurbulenceConfig(**turbulence)) if turbulence else cfg


@torch.no_grad()
def test_runs_inside_wind_estimate_on_real_features():
    """A WindEstimator by the protocol, driving WindEstimate in a short turbulent rollout."""
    from quadwind_trl.rl.envs import make_env, wind_estimate

    cfg = _steady_wind_config()
    est = WindUKF(config=cfg)
    assert isinstance(est, WindEstimator)
    env = make_env("horizontal", est, 2, config=cfg, compile_step=False)
    assert wind_estimate(env).ring.window == 60
    td = env.reset(scenario=make_scenarios(2, traj_id="racetrack_h", altitude_m=6.0, wind_speed_ref_m_s=6.0,
                                           wind_dir_deg=[30.0, 200.0], turb_intensity=0.15, turb_seed=[1, 2],
                                           sensor_seed=[3, 4], start_step=-1))
    for _ in range(25):
        td["action"] = torch.zeros(2, 4)
        td = env.step(td)["next"]
    assert torch.isfinite(td["wind_hat"]).all() and td["wind_hat"].abs().max() > 0


@torch.no_grad()
def test_estimates_the_mean_wind_of_a_real_hover():
    """The PD holds a hover for 12 s in a steady 8 m/s wind (turbulence off, sensors on, the
    stated model error), and the filter reads the last 6 s window. Against the wind its error is
    the closed-form model-error bias, -(1 - sqrt(0.95 / 1.15)) 8 = -0.73 m/s, within 0.15 m/s;
    across it, under 0.8 m/s: the body axis with little airspeed sees little drag (2.7 m/s gives
    0.07 m/s^2, near the accelerometer's 0.05 m/s^2 noise), so the accelerometer noise leaves a
    few tenths of a m/s there."""
    cfg = _steady_wind_config(enabled=False)
    scen = make_scenarios(2, traj_id="hover", altitude_m=20.0, wind_speed_ref_m_s=8.0, wind_dir_deg=[30.0, 250.0],
                          shear_alpha=0.0, sensor_seed=[5, 6], start_step=-1)
    keys = RAW_RECORD_KEYS + (("truth", "mean_wind"),)
    log = fly(QuadWindEnv(cfg, batch_size=(2,)), scen, log_keys=keys, progress=False).log
    features = make_extractor("horizontal", cfg).scan(log)
    truth = torch.stack((log["truth", "mean_wind"][:, -1, 1], log["truth", "mean_wind"][:, -1, 0]), -1)
    assert torch.allclose(truth.norm(dim=-1), torch.tensor(8.0), atol=0.01)
    est = WindUKF(config=cfg)
    err = est.predict(features[:, -est.window:]) - truth
    along_unit = truth / truth.norm(dim=-1, keepdim=True)
    along = (err * along_unit).sum(-1)
    across = err[:, 0] * along_unit[:, 1] - err[:, 1] * along_unit[:, 0]
    bias = -(1.0 - math.sqrt(est.cfg.mass_scale / est.cfg.drag_scale)) * 8.0
    assert (along - bias).abs().max() < 0.15, (along, bias)
    assert across.abs().max() < 0.8, across
