"""Vehicle dynamics against hand-derived values."""
from __future__ import annotations

import math
from dataclasses import replace

import torch

from quadwind_trl.config import GRAVITY_M_S2, VehicleConfig
from quadwind_trl.envs.rotations import quat_from_euler, quat_to_rotmat
from quadwind_trl.envs.vehicle import (
    RigidBody,
    VehicleParams,
    allocate,
    drag_force_body,
    physics_step,
    rotor_thrust_ratio,
)

CFG = VehicleConfig()
P = VehicleParams.from_config(CFG)


def test_drag_is_half_rho_cda_v_abs_v_per_axis():
    v = torch.tensor([[10.0, -4.0, 2.0], [0.0, 0.0, -7.5]])
    f = drag_force_body(v, P.drag_half_rho_cda)
    expected = torch.tensor(
        [
            [-0.5 * 1.225 * 0.038 * 100.0, 0.5 * 1.225 * 0.038 * 16.0, -0.5 * 1.225 * 0.10 * 4.0],
            [0.0, 0.0, 0.5 * 1.225 * 0.10 * 56.25],
        ]
    )
    torch.testing.assert_close(f, expected, rtol=1e-6, atol=1e-7)


def test_mixer_round_trip_and_layout():
    wrench = torch.tensor([[30.0, 0.2, -0.3, 0.05]])
    speeds = allocate(wrench, P)
    thrusts = P.thrust_coeff * speeds**2
    torch.testing.assert_close(thrusts @ P.mixer.T, wrench, rtol=1e-5, atol=1e-5)
    # a positive roll torque needs more thrust on the left rotors (0 and 1, at +y)
    roll = P.thrust_coeff * allocate(torch.tensor([[25.4, 0.5, 0.0, 0.0]]), P) ** 2
    assert roll[0, 0] > roll[0, 2] and roll[0, 1] > roll[0, 3]
    # a positive yaw torque comes from the CW rotors (0 and 2)
    yaw = P.thrust_coeff * allocate(torch.tensor([[25.4, 0.0, 0.0, 0.1]]), P) ** 2
    assert yaw[0, 0] > yaw[0, 1] and yaw[0, 2] > yaw[0, 3]


def test_collective_thrust_limits():
    hover = CFG.hover_thrust_n
    for asked, expected in ((100.0, 2.5 * hover), (1.0, 0.3 * hover)):
        speeds = allocate(torch.tensor([[asked, 0.0, 0.0, 0.0]]), P)
        total = (P.thrust_coeff * speeds**2).sum().item()
        assert abs(total - expected) < 1e-3 * expected


def _body(pos=(0.0, 0.0, 500.0), quat=(1.0, 0.0, 0.0, 0.0), omega=(0.0, 0.0, 0.0), rotor=0.0) -> RigidBody:
    return RigidBody(
        pos=torch.tensor([pos]),
        pos_carry=torch.zeros(1, 3),
        vel=torch.zeros(1, 3),
        quat=torch.tensor([quat]),
        omega=torch.tensor([omega]),
        rotor=torch.full((1, 4), rotor),
    )


def _advance(body: RigidBody, steps: int, rotor_cmd=None, wind=None, params: VehicleParams = P):
    rotor_cmd = body.rotor if rotor_cmd is None else rotor_cmd
    wind = torch.zeros(1, 3) if wind is None else wind
    sf = None
    for _ in range(steps):
        body, sf = physics_step(body, rotor_cmd, wind, params, 0.002)
    return body, sf


def test_motor_lag_reaches_63_percent_in_tau():
    body, _ = _advance(_body(), round(CFG.motor_time_constant_s / 0.002), rotor_cmd=torch.full((1, 4), 1000.0))
    assert abs(body.rotor[0, 0].item() / 1000.0 - (1 - math.exp(-1))) < 1e-4


def test_torque_free_spin_conserves_angular_momentum():
    quat = quat_from_euler(torch.tensor(0.3), torch.tensor(-0.2), torch.tensor(1.0))
    omega0 = (1.0, 2.0, 0.5)  # not about a principal axis: it precesses
    body = _body(quat=tuple(quat.tolist()), omega=omega0)
    inertia = torch.tensor(CFG.inertia_kg_m2)

    def momentum(b: RigidBody):
        return (quat_to_rotmat(b.quat) @ (inertia * b.omega).unsqueeze(-1)).squeeze(-1)

    l0 = momentum(body)
    body, _ = _advance(body, 1000)  # 2 s
    drift = (momentum(body) - l0).norm() / l0.norm()
    assert drift < 1e-4, drift
    assert (body.omega - torch.tensor([omega0])).norm() > 0.1  # it did precess


def test_free_fall_and_ground_contact():
    body, sf = _advance(_body(pos=(0.0, 0.0, 1.0)), 50)  # 0.1 s of free fall
    v = body.vel[0, 2].item()
    assert abs(v + GRAVITY_M_S2 * 0.1) < 2e-3  # drag barely matters yet
    # a falling accelerometer reads only the drag, 1/2 rho CdA_z v^2 / m upwards, at the velocity
    # the last step started from (semi-implicit Euler: v_end = v_start + dt (sf - g))
    v_start = v - 0.002 * (sf[0, 2].item() - GRAVITY_M_S2)
    drag_sf = 0.5 * 1.225 * 0.10 * v_start * v_start / CFG.mass_kg
    torch.testing.assert_close(sf, torch.tensor([[0.0, 0.0, drag_sf]]), rtol=1e-3, atol=1e-6)
    body, sf = _advance(body, 500)
    assert body.pos[0, 2].item() == 0.0 and body.vel.abs().max().item() == 0.0
    torch.testing.assert_close(sf, torch.tensor([[0.0, 0.0, GRAVITY_M_S2]]))  # the ground holds it up


def test_slow_motion_is_not_lost_to_float32_at_altitude():
    """0.5 mm/s at 600 m moves 1 um per 2 ms step, under half an ulp of 600 m in float32:
    without compensated summation the vehicle would never move. Static rotor thrust: the
    inflow model would (rightly) brake the climb, and the subject here is the position sum."""
    body = _body(pos=(0.0, 0.0, 600.0))
    body = body._replace(vel=torch.tensor([[0.0, 0.0, 5e-4]]))
    hover = math.sqrt(CFG.mass_kg * GRAVITY_M_S2 / (4 * CFG.thrust_coeff))
    body = body._replace(rotor=torch.full((1, 4), hover))
    moved, _ = _advance(body, 500, params=VehicleParams.from_config(replace(CFG, rotor_aero="static")))  # 1 s
    travelled = (moved.pos[0, 2] - 600.0).item() + moved.pos_carry[0, 2].neg().item()
    assert abs(travelled - 5e-4) < 5e-5, travelled


# --- rotor thrust with inflow (blade element + Glauert momentum) ---------------------------------

AERO = P.rotor


def _ratio(v_body, speed=None):
    v = torch.tensor(v_body, dtype=torch.float32).reshape(-1, 3)
    omega = torch.full((v.shape[0], 4), speed or CFG.hover_rotor_speed_rad_s)
    return rotor_thrust_ratio(v, omega, AERO)


def test_rotor_thrust_is_k_t_omega_squared_in_still_air():
    for speed in (300.0, CFG.hover_rotor_speed_rad_s, 1100.0):
        torch.testing.assert_close(_ratio([0.0, 0.0, 0.0], speed), torch.ones(1, 4), rtol=2e-6, atol=0.0)
    static = VehicleParams.from_config(replace(CFG, rotor_aero="static"))
    assert static.rotor is None


def test_axial_inflow_matches_the_closed_form_momentum_solution():
    """Without edgewise flow the two equations reduce to a quadratic in the inflow ratio, solved here
    independently of the Newton iteration; the model clamps descent at the hover induced velocity."""
    s, theta, tip = AERO.half_solidity_lift, AERO.pitch, CFG.hover_rotor_speed_rad_s * AERO.radius
    hover_induced = AERO.hover_inflow * tip
    for v_climb in (-5.0, -2.0, -0.5, 0.5, 2.5, 6.0, 12.0):
        lc = max(v_climb / tip, -AERO.hover_inflow)
        b = s / 4.0 - lc
        lam = (-b + math.sqrt(b * b + 4.0 * s * theta / 6.0)) / 2.0
        expected = s * (theta / 3.0 - lam / 2.0) / AERO.static_ct
        torch.testing.assert_close(_ratio([0.0, 0.0, v_climb])[0, 0].item(), expected, rtol=1e-5, atol=0.0)
    assert 7.0 < hover_induced < 7.3  # 7.2 m/s for 2.59 kg on four 10-inch rotors


def test_thrust_slope_in_climb_is_the_linearised_momentum_result():
    """d(T/T0)/dV_climb at hover = -(sigma a / 4) D / (C_T0 omega R), D = 1 / (2 (1 + sigma a / (16 lambda_h)))."""
    s, lh, tip = AERO.half_solidity_lift, AERO.hover_inflow, CFG.hover_rotor_speed_rad_s * AERO.radius
    slope = -(s / 2.0) / (2.0 * (1.0 + s / (8.0 * lh))) / (AERO.static_ct * tip)
    dv = 0.01
    numeric = (_ratio([0.0, 0.0, dv]) - _ratio([0.0, 0.0, -dv]))[0, 0].item() / (2 * dv)
    assert abs(numeric - slope) < 0.02 * abs(slope)
    assert -0.05 < slope < -0.035  # about 4 % of thrust per m/s of climb (or downdraught)


def test_edgewise_flow_raises_thrust_and_newton_has_converged_over_the_envelope():
    ratios = _ratio([[v, 0.0, 0.0] for v in (0.0, 2.0, 5.0, 10.0, 20.0)])[:, 0]
    assert (ratios.diff() > 0).all()  # translational lift
    # the inflow after the solve's fixed steps, against a 40-step solution
    grid = torch.tensor([[u, 0.0, w] for u in (0.0, 3.0, 10.0, 25.0, 35.0) for w in (-8.0, -3.0, 0.0, 2.0, 8.0, 15.0)])
    omega = torch.tensor([250.0, 651.0, 900.0, 1200.0]).expand(grid.shape[0], 4)
    from quadwind_trl.envs import vehicle

    steps = vehicle._INFLOW_NEWTON_STEPS
    try:
        vehicle._INFLOW_NEWTON_STEPS = 40
        converged = rotor_thrust_ratio(grid, omega, AERO)
    finally:
        vehicle._INFLOW_NEWTON_STEPS = steps
    torch.testing.assert_close(rotor_thrust_ratio(grid, omega, AERO), converged, rtol=1e-5, atol=0.0)


def test_newton_from_the_axial_solution_converges_as_far_as_four_steps_from_hover_did():
    """In float64 (no float32 rounding to hide behind), over a grid wider than the envelope: three
    steps from the axial-flow solution agree with forty to 1e-9 of the still-air thrust, where
    four from the hover inflow, the solve before it, reached 1.25e-9 (measured on this grid)."""
    from quadwind_trl.envs import vehicle

    u, w = torch.meshgrid(torch.linspace(0.0, 40.0, 81), torch.linspace(-10.0, 20.0, 61), indexing="ij")
    grid = torch.stack((u.flatten(), torch.zeros(u.numel()), w.flatten()), -1).double()
    omega = torch.tensor([150.0, 250.0, 400.0, 651.0, 900.0, 1200.0, 1500.0], dtype=torch.float64).expand(grid.shape[0], 7)
    steps = vehicle._INFLOW_NEWTON_STEPS
    assert steps == 3
    try:
        vehicle._INFLOW_NEWTON_STEPS = 40
        converged = rotor_thrust_ratio(grid, omega, AERO)
    finally:
        vehicle._INFLOW_NEWTON_STEPS = steps
    assert (rotor_thrust_ratio(grid, omega, AERO) - converged).abs().max().item() < 1e-9


def test_an_updraught_lifts_a_vehicle_at_hover_rotor_speed():
    """A 1 m/s updraught lowers the air's inflow through the discs: at hover rotor speed the thrust
    rises as in a 1 m/s descent, and the vehicle accelerates upwards at that fraction of g (plus
    the vertical drag of the body)."""
    body = _body(pos=(0.0, 0.0, 100.0))._replace(rotor=torch.full((1, 4), CFG.hover_rotor_speed_rad_s))
    _, sf = _advance(body, 1, wind=torch.tensor([[0.0, 0.0, 1.0]]))
    expected = _ratio([0.0, 0.0, -1.0])[0, 0].item() * GRAVITY_M_S2 + 0.5 * 1.225 * 0.10 / CFG.mass_kg
    torch.testing.assert_close(sf[0, 2].item(), expected, rtol=1e-5, atol=0.0)
    assert sf[0, 2].item() > GRAVITY_M_S2 * 1.03


def test_rotor_model_refuses_a_rotor_that_would_stall_and_bounds_the_advance_ratio():
    import pytest

    with pytest.raises(ValueError, match="rotor_radius_m=0.05"):
        VehicleParams.from_config(replace(CFG, rotor_radius_m=0.05))
    # a slow rotor in fast edgewise flow: beyond an advance ratio of 0.5 the thrust stops growing
    slow = 200.0
    at_limit = _ratio([0.5 * slow * AERO.radius, 0.0, 0.0], slow)
    beyond = _ratio([[3.0 * slow * AERO.radius, 0.0, 0.0]], slow)
    torch.testing.assert_close(beyond, at_limit, rtol=1e-6, atol=0.0)


def test_the_rotations_written_out_for_the_compiled_step_are_the_tables_expressions(monkeypatch):
    """Traced, quat_mul, quat_to_rotmat, euler_to_rotmat and vee_antisymmetric write their
    expressions out instead of reading the eager index tables (inductor fuses the former); both
    forms are the same products, so in float64 they agree to the last bit or two."""
    from quadwind_trl.envs import rotations

    gen = torch.Generator().manual_seed(0)
    q = torch.randn(500, 4, generator=gen, dtype=torch.float64)
    q = q / q.norm(dim=-1, keepdim=True)
    p = torch.randn(500, 4, generator=gen, dtype=torch.float64)
    angles = torch.randn(500, 3, generator=gen, dtype=torch.float64)
    m = torch.randn(500, 3, 3, generator=gen, dtype=torch.float64)

    def every_form():
        return (rotations.quat_mul(q, p), rotations.quat_to_rotmat(q), rotations.euler_to_rotmat(angles),
                rotations.vee_antisymmetric(m))

    eager = every_form()
    monkeypatch.setattr(rotations, "tracing", lambda: True)
    traced = every_form()
    for name, e, t in zip(("quat_mul", "quat_to_rotmat", "euler_to_rotmat", "vee_antisymmetric"), eager, traced):
        torch.testing.assert_close(t, e, rtol=0, atol=1e-15, msg=name)
