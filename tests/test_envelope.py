"""The flight envelope: closed forms by hand, how it moves with mass and drag, the simulator's PD
stopping where it says, and the demand against the atmosphere's own profile."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from quadwind_trl.config import GRAVITY_M_S2, ControllerConfig, EnvConfig, VehicleConfig
from quadwind_trl.envs import make_scenarios
from quadwind_trl.envs.envelope import flight_envelope, trim_thrust, trim_tilt
from quadwind_trl.envs.vehicle import VehicleParams
from quadwind_trl.evaluation.envelope import GUST_SIGMAS, airspeed_demand
from quadwind_trl.studies.envelope import edge_wind_speed, first_not_held, hold_check, sweep_cells
from quadwind_trl.regimes import HORIZONTAL_RL, HORIZONTAL_SWEEP

STATIC = replace(VehicleConfig(), rotor_aero="static")
TILT = math.radians(ControllerConfig().max_tilt_deg)


def _body_x_airspeed(v: VehicleConfig, tilt: float) -> float:
    """Thrust has no body-x part, so along body x the drag of the airspeed's cos(tilt) share
    balances the weight's sin(tilt) share: 1/2 rho CdA_xy V^2 cos^2 = m g sin."""
    return math.sqrt(2 * v.mass_kg * GRAVITY_M_S2 * math.sin(tilt) / (v.air_density_kg_m3 * v.drag_area_xy_m2 * math.cos(tilt) ** 2))


def test_tilt_limited_airspeed_is_the_body_axis_force_balance():
    env = flight_envelope(STATIC)
    assert env.tilt_limited_m_s == pytest.approx(_body_x_airspeed(STATIC, TILT), rel=1e-6)
    assert env.tilt_limited_m_s == pytest.approx(30.55, abs=0.01)
    # the z drag area drops out of the tilt limit (it acts along the thrust axis)
    assert flight_envelope(replace(STATIC, drag_area_z_m2=0.3)).tilt_limited_m_s == pytest.approx(env.tilt_limited_m_s, rel=1e-6)
    assert env.binding == "tilt" and env.airspeed_m_s == env.tilt_limited_m_s


def test_trim_matches_the_body_axis_balances():
    """At 20 m/s: the tilt from the body-x balance, the thrust from the body-z one
    (T = m g cos + 1/2 rho CdA_z (V sin)^2)."""
    p = VehicleParams.from_config(STATIC)
    v = torch.tensor([20.0], dtype=torch.float64)
    tilt = trim_tilt(v, p)
    assert _body_x_airspeed(STATIC, tilt.item()) == pytest.approx(20.0, rel=1e-5)
    t = tilt.item()
    expected = STATIC.mass_kg * GRAVITY_M_S2 * math.cos(t) + 0.5 * STATIC.air_density_kg_m3 * STATIC.drag_area_z_m2 * (20 * math.sin(t)) ** 2
    assert trim_thrust(v, tilt, p).item() == pytest.approx(expected, rel=1e-5)


def test_static_thrust_limit_by_hand():
    """Static rotors: the tilt at which m g cos + CdA_z-drag reaches the collective limit, by
    bisection here, gives the thrust-limited airspeed through the body-x balance."""
    weight, half_rho = STATIC.mass_kg * GRAVITY_M_S2, 0.5 * STATIC.air_density_kg_m3
    t_max = STATIC.collective_thrust_max_hover * weight
    low, high = 0.0, math.radians(89.0)
    for _ in range(60):
        tilt = 0.5 * (low + high)
        thrust = weight * math.cos(tilt) + half_rho * STATIC.drag_area_z_m2 * (_body_x_airspeed(STATIC, tilt) * math.sin(tilt)) ** 2
        low, high = (tilt, high) if thrust < t_max else (low, tilt)
    assert flight_envelope(STATIC).thrust_limited_m_s == pytest.approx(_body_x_airspeed(STATIC, tilt), abs=0.011)


def test_envelope_moves_the_right_way():
    base = flight_envelope()
    assert base.binding == "thrust"  # the momentum rotors lose thrust with the disc tilted into the flow
    assert base.thrust_limited_m_s < flight_envelope(STATIC).thrust_limited_m_s
    draggy = flight_envelope(replace(VehicleConfig(), drag_area_xy_m2=0.05))
    assert draggy.tilt_limited_m_s < base.tilt_limited_m_s and draggy.thrust_limited_m_s < base.thrust_limited_m_s
    weaker = flight_envelope(replace(VehicleConfig(), collective_thrust_max_hover=2.2))
    assert weaker.thrust_limited_m_s < base.thrust_limited_m_s and weaker.tilt_limited_m_s == base.tilt_limited_m_s
    # Mass is not "heavier holds less": at the tilt limit more weight is more horizontal thrust
    # (V ~ sqrt(m), exactly), and on the same rotors (the same collective limit in newtons) the
    # heavier vehicle balances the drag at a flatter attitude, exposing less of its larger
    # vertical drag area (and, with the momentum rotors, forcing less air down through its discs)
    heavy = flight_envelope(replace(VehicleConfig(), mass_kg=1.2 * VehicleConfig().mass_kg,
                                    collective_thrust_max_hover=VehicleConfig().collective_thrust_max_hover / 1.2))
    assert heavy.tilt_limited_m_s == pytest.approx(base.tilt_limited_m_s * math.sqrt(1.2), rel=1e-6)
    assert heavy.thrust_limited_m_s > base.thrust_limited_m_s
    assert flight_envelope(controller=ControllerConfig(max_tilt_deg=25.0)).tilt_limited_m_s < base.tilt_limited_m_s


def test_pd_holds_inside_the_envelope_and_drifts_at_the_rest_beyond_it():
    """Hovering PD, steady wind, static rotors: 1.5 m/s inside the edge it holds; 2 m/s beyond it
    is carried downwind at the wind minus the envelope's airspeed (within 1 %)."""
    edge = flight_envelope(STATIC).airspeed_m_s
    check = hold_check(replace(EnvConfig(), vehicle=STATIC), torch.tensor([edge - 1.5, edge + 2.0]), seconds=10.0, window_s=2.0)
    assert first_not_held(check) == pytest.approx(edge + 2.0)
    assert check["airspeed_held_m_s"][1] == pytest.approx(edge, rel=0.01)
    assert abs(check["altitude_change_m"][1]) < 1.0  # tilt-limited: altitude keeps priority


def test_demand_is_pattern_speed_plus_profile_plus_gusts():
    """U = 10 m/s at 10 m, shear 0.2, at 100 m: 10 * 10^0.2 mean; sigma_u = I x mean x 10^-0.05."""
    cfg = EnvConfig()
    sc = make_scenarios(2, wind_speed_ref_m_s=[10.0, 15.0], shear_alpha=0.2, turb_intensity=0.2, altitude_m=100.0)
    d = airspeed_demand(sc, cfg, 10.0)
    mean = 10.0 * 10**0.2
    sigma = 0.2 * mean * 10 ** -cfg.turbulence.intensity_altitude_exponent
    assert d["mean_wind"][0].item() == pytest.approx(mean, rel=1e-5)
    assert d["demand"][0].item() == pytest.approx(10.0 + mean + GUST_SIGMAS * sigma, rel=1e-5)
    assert d["mean_wind"][1].item() == pytest.approx(cfg.wind.max_horizontal_wind_m_s)  # the mean-wind cap


def test_sweep_cells_and_the_edge_by_hand():
    """The horizontal sweep's cells at 100 m, at the median and top shear of its range; the
    sustained edge where 10 + U 10^median reaches the envelope."""
    cfg, env = EnvConfig(), flight_envelope()
    low, high = HORIZONTAL_RL.shear_alpha
    rows = sweep_cells(HORIZONTAL_SWEEP, "horizontal", cfg, env)
    assert len(rows) == len(HORIZONTAL_SWEEP.wind_speeds) * len(HORIZONTAL_SWEEP.intensities)
    assert sum(r["cases"] for r in rows) == len(HORIZONTAL_SWEEP.wind_speeds) * len(HORIZONTAL_SWEEP.intensities) * HORIZONTAL_SWEEP.seeds
    cell = next(r for r in rows if r["wind_speed_m_s"] == 8.0 and r["intensity"] == 0.25)
    assert cell["median"]["shear_alpha"] == pytest.approx((low + high) / 2) and cell["worst"]["shear_alpha"] == pytest.approx(high)
    assert cell["worst"]["sustained"] == pytest.approx(10.0 + 8.0 * 10**high, rel=1e-5)
    assert cell["worst"]["margin"] == pytest.approx(env.airspeed_m_s - cell["worst"]["demand"])
    edge = edge_wind_speed(HORIZONTAL_RL, "horizontal", cfg, env, (0.1,))[0]
    assert edge["sustained"] == pytest.approx((env.airspeed_m_s - 10.0) / 10 ** ((low + high) / 2), abs=0.011)
    assert edge["I=0.1"] < edge["sustained"]
