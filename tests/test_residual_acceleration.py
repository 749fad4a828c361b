"""The residual on the outer loop (``ResidualConfig.acts_on="acceleration"``): the zero action is
the base law bit for bit, a correction moves the vehicle the way it says, its scales come from the
vehicle's drag in the RL regimes' strongest wind, bad settings fail at the boundary, and a policy
file records it (files without it act on the wrench)."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch
from tensordict import TensorDict

from quadwind_trl.config import (GRAVITY_M_S2, ControllerConfig, EnvConfig, MonitorConfig, ResidualConfig,
                                 TurbulenceConfig, with_sensing)
from quadwind_trl.envs import QuadWindEnv
from quadwind_trl.envs.controller import make_base_controller
from quadwind_trl.envs.rotations import heading_to_world
from quadwind_trl.envs.scenarios import make_scenarios
from quadwind_trl.envs.simulator import QuadSimulator
from quadwind_trl.envs.task import TrackingTask
from quadwind_trl.evaluation.ablation import policy_env_config
from quadwind_trl.keys import OBSERVATION_CHANNELS, RESIDUAL_CHANNELS, observation_channels
from quadwind_trl.manifest import CHECKPOINT_DIR
from quadwind_trl.regimes import HORIZONTAL_RL, VERTICAL_RL, regime_config
from quadwind_trl.rl.cli import build_parser, run, with_base_controller, with_residual_on
from quadwind_trl.rl.config import PPOConfig
from quadwind_trl.rl.envs import RLEnvSpec, make_env
from quadwind_trl.rl.policy import build_actor_critic, load_policy, network_dims, policy_payload, residual_target
from quadwind_trl.rl.screening import LEVERS
from quadwind_trl.transforms import PolicyObservation

from test_transforms import scenarios, short_config


def _on(base: str, target: str, hold: int = 10) -> EnvConfig:
    """The short test flights on base law ``base`` ("pd": the paper's), the residual on ``target``."""
    config, _ = with_base_controller("horizontal", short_config(), base)
    return with_residual_on(replace(config, timing=replace(config.timing, hold_control_steps=hold)), target)


def _fly(env: QuadWindEnv, action: torch.Tensor, steps: int) -> list[TensorDict]:
    td = env.reset(scenario=scenarios(3, start_step=[-1] * 3))
    out = []
    for _ in range(steps):
        td = env.step(td.set("action", action))["next"]
        out.append(td)
    return out


# --- the base law is the zero action --------------------------------------------------------------

@pytest.mark.parametrize("base", ["pd", "dob_inner"])
def test_the_zero_action_on_the_acceleration_flies_the_base_law_bit_for_bit(base):
    """With the paper's stateless PD (no term of its own in the outer loop) and with the observer on
    the stiffer inner loop (the base this lever is for), in wind, turbulence and sensor noise: every
    state, command, base state and reward equal to the bit."""
    wrench = QuadWindEnv(_on(base, "wrench"), batch_size=[3])
    accel = QuadWindEnv(_on(base, "acceleration"), batch_size=[3])
    flown = _fly(wrench, torch.zeros(3, 4), 25), _fly(accel, torch.zeros(3, 3), 25)
    for a, b in zip(*flown):
        for key in (("truth", "pos"), ("truth", "vel"), ("truth", "quat"), "pd_wrench", "cmd_wrench", "reward"):
            assert torch.equal(a[key], b[key]), key
    if base != "pd":
        assert torch.equal(wrench.state["base"]["force_hat"], accel.state["base"]["force_hat"])
    assert accel.state["control", "ff"].shape == (3, 3) and not accel.state["control", "ff"].any()


# --- a correction does what it says ---------------------------------------------------------------

def test_a_constant_correction_moves_the_vehicle_along_it_by_its_acceleration_over_the_position_gain():
    """Hovering in still air on the true state, a full-scale correction forward, left or up holds the
    vehicle displaced from the base law's own flight along that direction of the reference heading,
    by the correction over the position gain (the PD's equilibrium: kp e = a), and not across it."""
    cfg = with_sensing(_on("pd", "acceleration", hold=1), "true_state")
    cfg = replace(cfg, turbulence=replace(cfg.turbulence, enabled=False))
    sim = QuadSimulator(cfg)
    sc = make_scenarios(4, traj_id="hover", altitude_m=20.0, start_step=-1, wind_speed_ref_m_s=0.0)
    action = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    params, state = sim.initial(sc)
    for _ in range(800):  # 8 s: the 1 s build-up, then five of the horizontal loop's 0.57 s time constants
        state = sim.step(params, state, action)
    yaw = state["ref", "yaw"][:, 0]
    offset = state["body", "pos"] - state["body", "pos"][:1]  # against the base law alone (row 0)
    fwd = offset[:, 0] * torch.cos(yaw) + offset[:, 1] * torch.sin(yaw)
    left = -offset[:, 0] * torch.sin(yaw) + offset[:, 1] * torch.cos(yaw)
    up = offset[:, 2]
    scale, kp = cfg.residual.acceleration_scale_m_s2, cfg.controller.kp_pos
    expected = torch.tensor([[scale[0] / kp[0], 0.0, 0.0], [0.0, scale[1] / kp[1], 0.0], [0.0, 0.0, scale[2] / kp[2]]])
    torch.testing.assert_close(torch.stack((fwd, left, up), -1)[1:], expected, atol=0.01, rtol=0.0)


def test_the_heading_frame_turns_into_the_world_by_the_reference_heading():
    """Forward at a heading of 90 degrees (north) is north; left of it is west; up stays up."""
    vec = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    world = heading_to_world(vec, torch.full((3, 1), math.pi / 2))
    torch.testing.assert_close(world, torch.tensor([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))


def test_the_runtime_monitor_reads_the_base_thrust_and_zeroes_a_correction_on_the_acceleration():
    """A climb correction that asks more thrust than the monitor's fraction of the rotors' limit
    trips it through the base law's thrust (which holds the correction), and the correction is zero
    while it holds; with no correction the hover never comes near the limit."""
    cfg = with_sensing(_on("pd", "acceleration", hold=1), "true_state")
    # 6 m/s^2 up, in a few control steps (the position loop takes the thrust back to hover's once the
    # vehicle has moved), asks 1.6 times hover's thrust; the monitor trips at half the limit, 1.25 times
    residual = replace(cfg.residual, acceleration_scale_m_s2=(3.0, 3.0, 6.0),
                       acceleration_slew_m_s2_per_step=(0.03, 0.03, 6.0), monitor=MonitorConfig(thrust_fraction=0.5))
    sim = QuadSimulator(replace(cfg, residual=residual))
    params, state = sim.initial(make_scenarios(2, traj_id="hover", altitude_m=20.0, start_step=-1,
                                               wind_speed_ref_m_s=0.0))
    action = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    held = []
    for _ in range(300):
        state = sim.step(params, state, action)
        held.append(state["control", "monitor_left"][:, 0] > 0)
        assert not state["control", "ff"][held[-1]].any()
    held = torch.stack(held)
    assert not held[:, 0].any() and held[:, 1].any()


# --- the scales, from the vehicle ---------------------------------------------------------------

def test_the_scales_cover_the_drag_of_the_strongest_wind_within_the_tilt_limit_and_build_up_over_a_second():
    v, res, ctrl = EnvConfig().vehicle, ResidualConfig(), ControllerConfig()
    ratio_w = TurbulenceConfig().stability_ratios[2][1]  # convective: the largest sigma_w / sigma_u
    strongest = max(HORIZONTAL_RL.wind_speed_m_s[1], VERTICAL_RL.wind_speed_m_s[1])
    intensity = max(HORIZONTAL_RL.intensity[1], VERTICAL_RL.intensity[1])
    gust_xy = strongest * (1.0 + 2.0 * intensity)
    drag_xy = 0.5 * v.air_density_kg_m3 * v.drag_area_xy_m2 * gust_xy**2 / v.mass_kg
    trajectories = regime_config("vertical").trajectories
    climb = max(trajectories.vertical_climb_rate_m_s + (trajectories.climb_rate_m_s,))
    gust_z = climb + 2.0 * ratio_w * intensity * strongest
    drag_z = 0.5 * v.air_density_kg_m3 * v.drag_area_z_m2 * gust_z**2 / v.mass_kg
    fwd, left, up = res.acceleration_scale_m_s2
    assert drag_xy <= fwd == left <= GRAVITY_M_S2 * math.tan(math.radians(ctrl.max_tilt_deg))
    # up to the thrust's headroom over hover
    assert drag_z <= up <= GRAVITY_M_S2 * (v.collective_thrust_max_hover - 1.0)
    dt = EnvConfig().timing.control_dt_s
    for scale, slew in zip(res.acceleration_scale_m_s2, res.acceleration_slew_m_s2_per_step):
        assert scale / slew * dt == pytest.approx(1.0)


def test_the_effort_penalty_of_a_correction_is_that_of_the_force_it_asks_for():
    """A correction of a m/s^2 costs in the reward what a thrust wrench of m a newtons costs."""
    mass = EnvConfig().vehicle.mass_kg

    def penalty(target: str, ff_prev: list[float], ff: list[float]) -> torch.Tensor:
        cfg = with_residual_on(EnvConfig(), target)
        zero = torch.zeros(1, 3)

        def state(f):
            return TensorDict(body=TensorDict(pos=zero, batch_size=[1]), ref=TensorDict(pos=zero, batch_size=[1]),
                              control=TensorDict(ff=torch.tensor([f]), batch_size=[1]),
                              finite=torch.ones(1, 1, dtype=torch.bool), batch_size=[1])

        task = TrackingTask(cfg)
        return cfg.reward.alive_bonus - task.step_reward(None, state(ff_prev), state(ff))

    torch.testing.assert_close(penalty("acceleration", [0.5, 0.0, 0.0], [1.0, 2.0, 0.0]),
                               penalty("wrench", [0.5 * mass, 0.0, 0.0, 0.0], [mass, 2.0 * mass, 0.0, 0.0]))


# --- what the policy sees and sends ---------------------------------------------------------------

def test_the_env_takes_three_channels_and_the_observation_shows_the_applied_correction_over_its_scale():
    cfg = _on("dob_inner", "acceleration")
    rl_env = make_env("horizontal", None, 3, config=cfg, wind_input="truth", compile_step=False)
    assert rl_env.action_spec.shape == (3, 3)
    env = QuadWindEnv(cfg, batch_size=[3])
    assert "ff_acc" in env.observation_spec.keys() and "ff_wrench" not in env.observation_spec.keys()
    td = env.reset(scenario=scenarios(3, start_step=[-1] * 3))
    with pytest.raises(ValueError, match=r"expected \(3, 3\)"):
        env.step(td.clone().set("action", torch.zeros(3, 4)))
    td = env.step(td.set("action", torch.tensor([[1.0, -0.5, 0.25]] * 3)))["next"]
    ff = env.state["control", "ff"]
    assert torch.equal(td["ff_acc"], ff) and (ff[:, 0] > 0).all() and (ff[:, 1] < 0).all() and (ff[:, 2] > 0).all()
    obs = PolicyObservation(cfg)(td.set("wind_hat", torch.zeros(3, 2)))["observation"]
    channels = observation_channels("acceleration")
    assert obs.shape[-1] == len(channels) == len(OBSERVATION_CHANNELS) - 1
    assert channels[-3:] == RESIDUAL_CHANNELS["acceleration"]
    torch.testing.assert_close(obs[:, -3:], ff / torch.tensor(cfg.residual.acceleration_scale_m_s2))


# --- boundary checks ------------------------------------------------------------------------------

@pytest.mark.parametrize(("change", "field"), [
    ({"acts_on": "torque"}, "acts_on"),
    ({"acceleration_scale_m_s2": (3.0, 0.0, 1.5)}, "acceleration_scale_m_s2"),
    ({"acceleration_scale_m_s2": (3.0, 3.0, -1.5)}, "acceleration_scale_m_s2"),
    ({"acceleration_slew_m_s2_per_step": (0.03, 0.03, 0.0)}, "acceleration_slew_m_s2_per_step"),
])
def test_a_bad_residual_setting_is_refused_naming_the_field_and_the_allowed_values(change, field):
    with pytest.raises(ValueError, match=rf"ResidualConfig\.{field}=.*allowed"):
        ResidualConfig(**change).validate()
    with pytest.raises(ValueError, match=field):
        EnvConfig(residual=ResidualConfig(**change)).validate()


def test_a_base_law_that_cannot_take_the_correction_is_refused_on_the_acceleration():
    class Own:  # a user's law: the protocol without takes_acc_correction
        def __init__(self, law):
            self.law, self.needs_wind = law, False

        def init_state(self, n, device):
            return self.law.init_state(n, device)

        def __call__(self, inputs, state):
            return self.law(inputs, state)

    cfg = EnvConfig()
    own = Own(make_base_controller(cfg.controller, cfg.vehicle, cfg.timing.control_dt_s))
    QuadSimulator(cfg, controller=own)  # on the wrench it needs nothing more
    with pytest.raises(ValueError, match=r"acts_on='acceleration'.*takes_acc_correction"):
        QuadSimulator(with_residual_on(cfg, "acceleration"), controller=own)


# --- the policy file ------------------------------------------------------------------------------

def test_a_policy_on_the_acceleration_is_saved_and_loaded_with_its_three_actions(tmp_path):
    spec = RLEnvSpec(config=_on("dob_inner", "acceleration"), compile_step=False, untrained_estimator=True)
    dims = network_dims(spec)
    assert dims["action_dim"] == 3 and dims["obs_dim"] == len(observation_channels("acceleration"))
    actor, _ = build_actor_critic(PPOConfig(hidden=(8, 8)), **dims)
    torch.save(policy_payload(actor, {}, PPOConfig(hidden=(8, 8)), spec), tmp_path / "policy.pt")
    loaded, payload = load_policy(tmp_path / "policy.pt")
    assert payload["observation_channels"][-3:] == list(RESIDUAL_CHANNELS["acceleration"])
    assert policy_env_config(payload).residual.acts_on == "acceleration"
    out = loaded(TensorDict(observation=torch.zeros(2, dims["obs_dim"]), batch_size=[2]))
    assert out["action"].shape == (2, 3)


def test_a_policy_file_from_before_the_setting_acts_on_the_wrench():
    _, payload = load_policy(CHECKPOINT_DIR / "policy_horizontal.pt")
    assert "acts_on" not in payload["env_spec"]["env_config"]["residual"]  # saved before it existed
    assert residual_target(payload["env_spec"]) == "wrench"
    assert policy_env_config(payload).residual.acts_on == "wrench"
    assert network_dims(payload["env_spec"])["action_dim"] == 4


def test_the_catalogue_lever_trains_a_quick_run_on_the_acceleration(tmp_path):
    args = build_parser("horizontal", "").parse_args([*LEVERS["horizontal"]["accel_residual"], "--untrained-estimator",
                                                      "--quick", "--base-controller", "dob_inner", "--no-progress",
                                                      "--out", str(tmp_path / "run")])
    manifest = run("horizontal", args)
    assert manifest["env_spec"]["env_config"]["residual"]["acts_on"] == "acceleration"
    assert manifest["frames"] == 4 * 8 * 32 and math.isfinite(manifest["metrics"]["rmse"])
    actor, payload = load_policy(tmp_path / "run" / "policy.pt")
    assert network_dims(payload["env_spec"])["action_dim"] == 3
