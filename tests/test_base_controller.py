"""The base controller (envs/controller.py): the paper's PD unchanged by default; each classical
law against its closed form in a steady wind (PID: no steady-state error; wind feed-forward: exact
cancellation with the true model; observer: the filter's step response and the drag it converges
to; L1: the fraction of a constant force its adaptation law settles at); the base law is the zero action; the wind estimate's way into the step; the validation
search's per-row batching. Eager, one to four rows, hovering in still turbulence."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch
from torchrl.envs.utils import check_env_specs

from quadwind_trl.config import ControllerConfig, EnvConfig, TrajectoryConfig, VehicleConfig, stiffer_inner_loop
from quadwind_trl.envs import QuadWindEnv, make_scenarios
from quadwind_trl.envs.controller import (ClassicalParams, ControlInputs, ControllerParams, make_base_controller,
                                          pd_control)
from quadwind_trl.envs.simulator import QuadSimulator
from quadwind_trl.envs.trajectories.library import Reference
from quadwind_trl.studies.base_search import fly_candidates, per_row_controller
from quadwind_trl.keys import BASE_WIND_KEY
from quadwind_trl.rl.envs import make_env
from quadwind_trl.transforms import BaseWindInput

from conftest import quiet_config

WIND_M_S = 8.0
ALTITUDE_M = 20.0
HOVER_S = 8.0


def _steady(controller: ControllerConfig) -> EnvConfig:
    """Hover in a steady wind: truth feedback, no turbulence, no sensor noise, the static rotor (so
    the wind's only force is the airframe's drag), one decision per 10 control steps."""
    cfg = quiet_config(controller=replace(controller, feedback="truth"), vehicle=VehicleConfig(rotor_aero="static"),
                       trajectories=TrajectoryConfig(hover_duration_s=HOVER_S))
    return replace(cfg, timing=replace(cfg.timing, hold_control_steps=10))


def _hover_scenarios(n: int):
    return make_scenarios(n, traj_id="hover", altitude_m=ALTITUDE_M, wind_speed_ref_m_s=WIND_M_S, turb_intensity=0.0,
                          start_step=-1)


def _fly_hover(env: QuadWindEnv, wind_ne: torch.Tensor | None = None) -> torch.Tensor:
    """``[N, 3]`` the position error (true minus reference) at the end of the hover."""
    n = env.batch_size[0]
    td = env.reset(scenario=_hover_scenarios(n))
    for _ in range(int(HOVER_S / env.config.timing.control_dt_s) // env.config.timing.hold_control_steps - 1):
        td["action"] = torch.zeros(n, 4)
        if wind_ne is not None:
            td[BASE_WIND_KEY] = wind_ne
        td = env.step(td)["next"]
    return td["truth", "pos"] - td["ref_pos"]


def _drag_n(cfg: EnvConfig, air_speed: float) -> float:
    return 0.5 * cfg.vehicle.air_density_kg_m3 * cfg.vehicle.drag_area_xy_m2 * air_speed**2


def _mean_wind_ne(env: QuadWindEnv) -> torch.Tensor:
    mean = env.state["wind", "mean"]
    return torch.stack((mean[..., 1], mean[..., 0]), -1)


def test_default_is_the_papers_pd_with_no_state():
    """The default base law is stateless and computes exactly ``pd_control`` (the replay records,
    tests/test_replay.py, pin its physics bit for bit)."""
    cfg = EnvConfig()
    law = make_base_controller(cfg.controller, cfg.vehicle, cfg.timing.control_dt_s)
    assert law.init_state(3, torch.device("cpu")) is None and not law.needs_wind
    gen = torch.Generator().manual_seed(0)
    r = lambda *s: torch.randn(*s, generator=gen)  # noqa: E731
    rot = torch.linalg.qr(r(3, 3, 3))[0]
    rot = rot * torch.linalg.det(rot).sign()[:, None, None]
    ref = Reference(r(3, 3), r(3, 3), r(3, 3), r(3, 3), r(3, 1), r(3, 1))
    x = ControlInputs(r(3, 3), r(3, 3), rot, r(3, 3), ref, r(3, 3), r(3, 1), None, torch.ones(3, 1, dtype=torch.bool), False)
    out, state = law(x, None)
    expected = pd_control(x.pos, x.vel, rot, x.omega, ref.pos, ref.vel, ref.acc, ref.jerk, ref.yaw, ref.yaw_rate,
                          ControllerParams.from_config(cfg.controller, cfg.vehicle))
    assert state is None
    assert torch.equal(out.wrench, expected.wrench) and torch.equal(out.tilt_cmd, expected.tilt_cmd)
    sim = QuadSimulator(cfg)
    _, initial = sim.initial(make_scenarios(2))
    assert "base" not in initial.keys()


def test_pid_removes_the_steady_offset_pd_keeps():
    """In a steady wind PD settles where its position gain balances the drag, ``e = F / (m Kp)``;
    the same PD with integral action settles on the reference. Both in one batch (PD is the
    integral family's ``Ki = 0`` row)."""
    pid = ControllerConfig(ki_pos=(4.0, 4.0, 4.0))
    cfg = _steady(pid)
    candidates = [replace(pid, ki_pos=(0.0, 0.0, 0.0)), pid]
    env = QuadWindEnv(cfg, batch_size=[2], controller=per_row_controller(candidates, torch.arange(2), cfg))
    err = _fly_hover(env)
    wind = _mean_wind_ne(env)[0].norm().item()
    pd_offset = _drag_n(cfg, wind) / (cfg.vehicle.mass_kg * cfg.controller.kp_pos[0])
    assert err[0, :2].norm().item() == pytest.approx(pd_offset, rel=0.02)
    assert err[1].norm().item() < 0.01 * pd_offset
    # the integral holds the force the PD offset held: Ki I = F / m
    assert env.state["base", "integral"][1, :2].norm().item() * 4.0 == pytest.approx(
        _drag_n(cfg, wind) / cfg.vehicle.mass_kg, rel=0.02)


def test_wind_feedforward_cancels_a_steady_wind_and_its_blind_twin_does_not():
    """Fed the true mean wind, the feed-forward predicts the airframe's drag exactly and the vehicle
    holds the reference; with the estimate at zero (its blind twin) it is PD again."""
    cfg = _steady(ControllerConfig(disturbance="wind_model"))
    env = QuadWindEnv(cfg, batch_size=[2])
    sim_wind = torch.stack((_steady_wind_ne(cfg), torch.zeros(2)))
    err = _fly_hover(env, sim_wind)
    pd_offset = _drag_n(cfg, sim_wind[0].norm().item()) / (cfg.vehicle.mass_kg * cfg.controller.kp_pos[0])
    assert err[0].norm().item() < 0.01 * pd_offset
    assert err[1, :2].norm().item() == pytest.approx(pd_offset, rel=0.02)


def _steady_wind_ne(cfg: EnvConfig) -> torch.Tensor:
    """The mean wind at the hover point, from the simulator's own profile."""
    sim = QuadSimulator(cfg)
    _, state = sim.initial(_hover_scenarios(1))
    mean = state["wind", "mean"][0]
    return torch.stack((mean[1], mean[0]))


def _hover_law(controller: ControllerConfig, dt: float):
    """The steady-hover config of ``controller``, its law at ``dt`` with one row's initial state,
    and the vehicle's mass and weight."""
    cfg = _steady(controller)
    law = make_base_controller(controller, cfg.vehicle, dt)
    return cfg, law, law.init_state(1, torch.device("cpu")), cfg.vehicle.mass_kg, cfg.vehicle.mass_kg * 9.81


def _level_inputs(vel: torch.Tensor, specific_force: torch.Tensor, thrust_n: float, first: bool = False) -> ControlInputs:
    """What a law reads on one level, armed vehicle at the origin with a zero reference."""
    ref = Reference(*(torch.zeros(1, 3),) * 4, torch.zeros(1, 1), torch.zeros(1, 1))
    return ControlInputs(torch.zeros(1, 3), vel, torch.eye(3).expand(1, 3, 3), torch.zeros(1, 3), ref, specific_force,
                         torch.full((1, 1), thrust_n), None, torch.ones(1, 1, dtype=torch.bool), first)


def test_observer_filter_is_first_order_and_converges_to_the_drag():
    """The observer's force follows a constant disturbance as ``1 - exp(-t / tau)`` (one step of the
    filter checked against the closed form), and in flight it converges to the drag the wind
    exerts, so the vehicle holds the reference."""
    tau, dt = 0.2, 0.01
    cfg, law, state, mass, weight = _hover_law(ControllerConfig(disturbance="observer", observer_tau_s=tau), dt)
    push = torch.tensor([[1.5, -0.5, 0.0]])  # N, a constant external force on a level vehicle
    for k in range(1, 31):
        _, state = law(_level_inputs(torch.zeros(1, 3), (push + torch.tensor([[0.0, 0.0, weight]])) / mass, weight), state)
        expected = push * (1.0 - math.exp(-k * dt / tau))
        torch.testing.assert_close(state["force_hat"], expected, rtol=1e-4, atol=1e-5)

    env = QuadWindEnv(cfg, batch_size=[1])
    err = _fly_hover(env)
    wind = _mean_wind_ne(env)[0].norm().item()
    assert env.state["base", "force_hat"][0, :2].norm().item() == pytest.approx(_drag_n(cfg, wind), rel=0.02)
    assert err[0].norm().item() < 0.05 * _drag_n(cfg, wind) / (mass * cfg.controller.kp_pos[0])


def test_l1_settles_at_its_closed_form_and_cancels_the_drag():
    """L1's piecewise-constant adaptation law, under a constant force ``F`` on a vehicle that
    accelerates under it, settles at ``exp(-a dt) F`` (its one-sample lag; the low-pass filter
    passes a constant whole), and in flight its force converges to that fraction of the drag, so
    the vehicle holds the reference to the remaining few per cent of PD's offset."""
    pole, tau, dt = 5.0, 0.05, 0.01
    cfg, law, state, mass, weight = _hover_law(ControllerConfig(disturbance="l1", observer_tau_s=tau, l1_pole_1_s=pole), dt)
    push = torch.tensor([[1.5, -0.5, 0.8]])  # N, a constant external force on a level vehicle
    for k in range(0, 301):
        vel = push / mass * (k * dt)  # the thrust holds the weight: the push alone accelerates it
        _, state = law(_level_inputs(vel, torch.zeros(1, 3), weight, first=k == 0), state)
        if k == 0:
            assert torch.equal(state["vel_hat"], vel)  # the predictor starts on the velocity it reads
    torch.testing.assert_close(state["force_hat"], push * math.exp(-pole * dt), rtol=1e-4, atol=1e-5)

    env = QuadWindEnv(cfg, batch_size=[1])
    err = _fly_hover(env)
    drag = _drag_n(cfg, _mean_wind_ne(env)[0].norm().item())
    assert env.state["base", "force_hat"][0, :2].norm().item() == pytest.approx(math.exp(-pole * dt) * drag, rel=0.02)
    pd_offset = drag / (mass * cfg.controller.kp_pos[0])
    assert err[0].norm().item() < 0.1 * pd_offset


@pytest.mark.parametrize("controller", [ControllerConfig(ki_pos=(1.0, 1.0, 1.0)),
                                        ControllerConfig(disturbance="observer"),
                                        ControllerConfig(disturbance="l1"),
                                        ControllerConfig(ki_pos=(1.0, 1.0, 1.0), disturbance="wind_model")],
                         ids=["pid", "observer", "l1", "pid_ff"])
def test_zero_action_is_the_base_law(controller):
    """The residual policy's zero action applies the base law's wrench exactly, whatever the law;
    the law's state restarts at a reset."""
    cfg = replace(EnvConfig(), controller=controller)
    env = make_env("horizontal", None, 2, wind_input="truth", base_wind_input="truth", config=cfg, compile_step=False,
                   start="pattern")
    td = env.reset()
    for _ in range(5):
        td["action"] = torch.zeros(2, 4)
        law = td["pd_wrench"]  # the base law's wrench for the step about to be flown
        td = env.step(td)["next"]
        assert torch.equal(td["cmd_wrench"], law)
    base = env.base_env.state["base"]
    assert any(v.abs().sum() > 0 for v in base.values())
    start = env.reset()
    restarted = env.base_env.state["base"]
    for key, value in restarted.items():
        # L1's predictor starts on the velocity the law reads at the episode's first instant
        expected = start["nav_vel"] if key == "vel_hat" else env.base_env.sim.controller.init_state(2, torch.device("cpu"))[key]
        torch.testing.assert_close(value, expected)


@pytest.mark.parametrize("source", ["truth", "zero"])
def test_base_wind_input_gives_the_step_its_wind(source):
    """``BaseWindInput`` hides the base env's wind input from the outer env (a user or a collector
    gives only the action) and gives the step the wind it saw last: the true mean wind, or zero."""
    cfg = replace(EnvConfig(), controller=ControllerConfig(disturbance="wind_model"))
    env = make_env("horizontal", None, 2, wind_input="truth", base_wind_input=source, config=cfg, compile_step=False,
                   start="pattern")
    assert BASE_WIND_KEY in env.base_env.full_state_spec.keys()
    assert BASE_WIND_KEY not in env.full_state_spec.keys()
    check_env_specs(env)
    held = next(t for t in env.transform if isinstance(t, BaseWindInput))
    td = env.reset()
    mean = td["truth", "mean_wind"]
    expected = torch.stack((mean[..., 1], mean[..., 0]), -1)
    assert torch.equal(held.held, expected if source == "truth" else torch.zeros_like(expected))
    raw = QuadWindEnv(cfg, batch_size=[2])
    raw.reset()
    with pytest.raises(KeyError, match=BASE_WIND_KEY):
        raw.step(raw.full_action_spec.zero().update({"action": torch.zeros(2, 4)}))


@pytest.mark.parametrize("family", ["observer_tau", "inner_loop", "tilt_limit"])
def test_search_rows_fly_their_own_candidate(family):
    """The validation search flies each candidate's copy of the episodes with that candidate's
    constants (the observer's filter, or the inner loop's gains): a batch of two candidates gives
    each candidate's results flown alone, to float rounding (other batch layout), on episodes of
    different lengths (the runner's flight order). Candidates that differ in the outer loop (the
    tilt limit) fly a batch each, so each is its flight alone."""
    cfg = _steady(ControllerConfig(disturbance="observer"))
    cfg = replace(cfg, trajectories=replace(cfg.trajectories, hover_duration_s=2.0, horizontal_duration_s=3.0),
                  timing=replace(cfg.timing, hold_control_steps=1))
    scenarios = make_scenarios(2, traj_id=["hover", "lawnmower_h"], altitude_m=5.0, wind_speed_ref_m_s=6.0,
                               turb_intensity=0.0, start_step=-1)
    dob = ControllerConfig(feedback="truth", disturbance="observer")
    candidates = {"observer_tau": [replace(dob, observer_tau_s=t) for t in (0.1, 1.0)],
                  "inner_loop": [stiffer_inner_loop(dob, s) for s in (1.0, 4.0)],
                  # 10 deg: at most 1.7 m/s^2 of horizontal acceleration, less than the pattern's turns ask
                  "tilt_limit": [replace(dob, max_tilt_deg=t) for t in (10.0, 35.0)]}[family]
    both = fly_candidates("horizontal", candidates, scenarios, base_wind_input="zero", config=cfg)
    for candidate, result in zip(candidates, both):
        alone = fly_candidates("horizontal", [candidate], scenarios, base_wind_input="zero", config=cfg)[0]
        torch.testing.assert_close(result.rmse_xy, alone.rmse_xy, rtol=1e-4, atol=1e-6)
        torch.testing.assert_close(result.rmse_z, alone.rmse_z, rtol=1e-4, atol=1e-6)
    assert not torch.allclose(both[0].rmse_xy, both[1].rmse_xy, rtol=1e-3)


@pytest.mark.parametrize("change, field", [
    (dict(ki_pos=(-1.0, 0.0, 0.0)), "ki_pos[0]"),
    (dict(integral_limit_m_s=(3.0, 3.0, -1.0)), "integral_limit_m_s"),
    (dict(disturbance="gps"), "disturbance"),
    (dict(observer_tau_s=-0.01), "observer_tau_s"),
    (dict(observer_reads="gps"), "observer_reads"),
    (dict(observer_reads="true_specific_force", disturbance="l1"), "observer_reads"),
    (dict(l1_pole_1_s=0.0), "l1_pole_1_s"),
])
def test_bad_classical_settings_name_the_field(change, field):
    with pytest.raises(ValueError, match=field.replace("[", r"\[").replace("]", r"\]")):
        replace(EnvConfig(), controller=replace(ControllerConfig(), **change)).validate()


def test_recipes_train_on_any_classical_base():
    """``--base-controller``: the regime's classical law with its validated constants, and what its
    wind feed-forward flies on; "pd" leaves the paper's cascade as it is."""
    from quadwind_trl.regimes import CLASSICAL_CHOICES, CLASSICAL_CONTROLLERS
    from quadwind_trl.rl.cli import with_base_controller

    cfg = EnvConfig()
    assert with_base_controller("vertical", cfg, "pd") == (cfg, "estimate")
    pid_ff, wind = with_base_controller("vertical", cfg, "pid_ff")
    assert wind == "estimate" and pid_ff.controller.disturbance == "wind_model"
    assert pid_ff.controller.ki_pos == (CLASSICAL_CHOICES["vertical"]["pid_ff_ki"],) * 3
    assert pid_ff.controller.kp_pos == cfg.controller.kp_pos  # the paper's PD underneath
    assert with_base_controller("horizontal", cfg, "pd_ff_blind")[1] == "zero"
    assert with_base_controller("horizontal", cfg, "pd_ff_oracle")[1] == "truth"
    for name in CLASSICAL_CONTROLLERS:
        with_base_controller("horizontal", cfg, name)[0].validate()


def test_search_recipe_writes_its_table(tmp_path):
    """``recipes/tune_base_controllers.py --quick``: every candidate's row against PD, the kept
    value by the search's rule, and the provenance a results file carries."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    from quadwind_trl.studies.base_search import select_candidate

    root = Path(__file__).resolve().parent.parent
    out = subprocess.run([sys.executable, "recipes/tune_base_controllers.py", "--quick", "--regimes", "horizontal",
                          "--families", "l1", "dob_inner_tilt", "--results", str(tmp_path)], cwd=root, capture_output=True,
                         text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    result = json.loads((tmp_path / "base_search_horizontal.json").read_text())
    family = result["families"]["l1"]
    assert [row["value"] for row in family["candidates"]] == [0.2, 0.8]
    assert [row["value"] for row in result["families"]["dob_inner_tilt"]["candidates"]] == [35.0, 45.0]
    assert family["chosen"] == select_candidate(family["candidates"], result["pd"]["crashed"])["value"]
    assert result["pd"]["improvement_xy_pct"] == 0.0 and result["episodes"] == 3
    assert {"command", "git_commit", "platform", "estimate"} <= set(result)


def test_search_recipe_keeps_the_families_it_does_not_fly(tmp_path):
    """A run of some families keeps an existing file's others, and refuses to when that file was
    flown in other conditions (another env, estimate, episodes, step or PD)."""
    import importlib.util
    import json
    from pathlib import Path

    path = Path(__file__).resolve().parent.parent / "recipes" / "tune_base_controllers.py"
    spec = importlib.util.spec_from_file_location("tune_base_controllers", path)
    recipe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(recipe)
    out = tmp_path / "base_search_horizontal.json"
    assert recipe.kept_families(out, ["l1"]) == {}
    earlier = {"config": {"kp_pos": [5.0, 5.0, 7.0]}, "estimate": {"ema_tau_s": 1.0}, "episodes": 45, "compile_step": True,
               "pd": {"rmse_xy": 0.5}, "families": {"dob": {"chosen": 0.02}, "l1": {"chosen": 0.4}},
               "git_commit": "abc1234", "command": "python recipes/tune_base_controllers.py"}
    out.write_text(json.dumps(earlier))
    assert recipe.kept_families(out, ["l1"]) == {"dob": {"chosen": 0.02, "git_commit": "abc1234",
                                                         "command": "python recipes/tune_base_controllers.py"}}
    # tuples, as a config dict holds them, and a setting added since (absent from the earlier file)
    now = {**earlier, "config": {"kp_pos": (5.0, 5.0, 7.0), "l1_pole_1_s": 5.0}}
    recipe.check_same_flights(out, now)
    with pytest.raises(SystemExit, match="'config' differs"):
        recipe.check_same_flights(out, {**now, "config": {"kp_pos": (5.0, 5.0, 8.0)}})
    with pytest.raises(SystemExit, match="'pd' differs"):
        recipe.check_same_flights(out, {**now, "pd": {"rmse_xy": 0.6}})


def test_the_report_names_the_run_that_flew_each_family():
    """A search file whose families were flown by different runs says which run flew which."""
    from quadwind_trl.studies.base_search import classical_section

    def row(value, score):
        return dict(value=value, validation_score=score, rmse_xy=0.3, improvement_xy_pct=40.0, rmse_z=0.2,
                    improvement_z_pct=20.0, wins=45, episodes=45, crashed=0)

    search = {"episodes": 45, "command": "python recipes/tune_base_controllers.py --families l1", "git_commit": "bbb2222",
              "compile_step": True, "pd": {**row(None, 1.0), "rmse_xy": 0.5, "rmse_z": 0.3},
              "families": {"dob": {"field": "observer_tau_s", "git_commit": "aaa1111", "command": "python recipes/tune_base_controllers.py",
                                   "candidates": [row(0.02, 0.6), row(0.1, 0.7)]},
                           "l1": {"field": "observer_tau_s", "git_commit": "bbb2222", "command": "python recipes/tune_base_controllers.py --families l1",
                                  "candidates": [row(0.02, 0.65), row(0.1, 0.62)]}}}
    text = classical_section({"horizontal": search}, {})
    assert "Flown by another run: PD + disturbance observer: `python recipes/tune_base_controllers.py` at `aaa1111`." in text
    assert "| PD + L1 adaptive | tau (s) = 0.1 **(chosen)** | 0.620 |" in text


def test_stiffer_inner_loop_keeps_the_attitude_damping():
    """``K_R x s`` with ``K_omega x sqrt(s)``: the attitude loop's damping ratio
    ``K_omega / (2 sqrt(J K_R))`` is unchanged and its natural frequency ``sqrt(K_R / J)`` is
    ``sqrt(s)`` times the paper's; a non-positive scale is refused."""
    paper, inertia = ControllerConfig(), VehicleConfig().inertia_kg_m2
    stiff = stiffer_inner_loop(paper, 4.0)
    for axis, j in enumerate(inertia):
        zeta = lambda c: c.k_rate[axis] / (2 * math.sqrt(j * c.k_att[axis]))  # noqa: E731
        assert zeta(stiff) == pytest.approx(zeta(paper), rel=1e-12)
        assert math.sqrt(stiff.k_att[axis] / j) == pytest.approx(2 * math.sqrt(paper.k_att[axis] / j), rel=1e-12)
    with pytest.raises(ValueError, match="scale=0"):
        stiffer_inner_loop(paper, 0.0)


def test_the_tilt_limited_observer_is_dob_inner_with_its_chosen_tilt_limit():
    """``dob_inner_tilt`` is ``dob_inner`` with the commanded-tilt limit its validation search
    chose; every other law sets the paper's limit, so a config that had another (a policy trained
    on this base) flies exactly the law named."""
    from quadwind_trl.regimes import CLASSICAL_CHOICES, classical_controller

    for regime in ("horizontal", "vertical"):
        inner, _ = classical_controller(regime, "dob_inner")
        tilt, wind = classical_controller(regime, "dob_inner_tilt")
        assert wind == "zero" and tilt == inner | {"max_tilt_deg": CLASSICAL_CHOICES[regime]["dob_inner_tilt_deg"]}
        assert inner["max_tilt_deg"] == ControllerConfig().max_tilt_deg == 35.0
        wide = replace(ControllerConfig(), **tilt)
        assert replace(wide, **classical_controller(regime, "pid")[0]).max_tilt_deg == 35.0
