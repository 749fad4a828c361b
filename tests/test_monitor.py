"""The runtime monitor (config.MonitorConfig, envs/monitor.py): off it changes nothing; near a
limit the residual is zero at once; the hold; partial resets; the validation recipe. Eager steps,
tiny batches."""
from __future__ import annotations

import importlib.util
import json
import math
import sys
from dataclasses import replace
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from quadwind_trl.config import EnvConfig, MonitorConfig, ResidualConfig, config_from_dict, config_to_dict, with_monitor
from quadwind_trl.envs import QuadWindEnv, make_scenarios
from quadwind_trl.envs.rotations import quat_from_euler
from quadwind_trl.envs.runner import FlightResults
from quadwind_trl.envs.simulator import QuadSimulator
from quadwind_trl.envs.vehicle import VehicleParams
from quadwind_trl.evaluation.policy_validation import monitor_authority
from quadwind_trl.keys import MEAS_KEY, MONITOR_KEY
from quadwind_trl.rl.paired import paired_metrics

from conftest import quiet_config

ROOT = Path(__file__).resolve().parent.parent
PUSH = torch.tensor([[1.0, 1.0, -1.0, 1.0]])  # a residual on every channel
# a monitor no calm flight trips: the widest tilt margin, the full thrust limit, no height check
NEVER = MonitorConfig(tilt_margin_deg=45.0, thrust_fraction=1.0, height_below_ref_m=None, hold_s=0.0)


def _hover(cfg: EnvConfig, n: int = 1):
    sim = QuadSimulator(cfg)
    sc = make_scenarios(n, traj_id="hover", altitude_m=30.0, start_step=-1, wind_speed_ref_m_s=0.0, turb_intensity=0.0,
                        sensor_seed=torch.arange(n) + 3)
    return (sim, *sim.initial(sc))


def _fly(sim: QuadSimulator, params, state, steps: int, action=PUSH) -> list[TensorDict]:
    out = []
    for _ in range(steps):
        state = sim.step(params, state, action.expand(state.batch_size[0], 4))
        out.append(state)
    return out


def test_monitor_off_adds_no_state_and_a_monitor_that_never_trips_changes_no_bit():
    # a config saved before the monitor (no field) loads with it off, and the state has no monitor entry
    saved = config_to_dict(EnvConfig())
    del saved["residual"]["monitor"]
    assert config_from_dict(EnvConfig, saved) == EnvConfig() and EnvConfig().residual.monitor is None
    on = with_monitor(EnvConfig(), NEVER)
    assert config_from_dict(EnvConfig, json.loads(json.dumps(config_to_dict(on)))) == on  # and round-trips when on
    cfg = replace(EnvConfig(), trajectories=replace(EnvConfig().trajectories, horizontal_duration_s=5.0))
    sim, params, state = _hover(cfg, 2)
    assert "monitor_left" not in state["control"].keys()
    off = _fly(sim, params, state, 60)
    sim_on, params_on, state_on = _hover(with_monitor(cfg, NEVER), 2)
    assert list(state_on["control"].keys()) == list(state["control"].keys())[:2] + ["monitor_left"] + list(
        state["control"].keys())[2:]  # initial()'s key order is the step's
    gated = _fly(sim_on, params_on, state_on, 60)
    assert not any(bool(s["control", "monitor_left"].any()) for s in gated)
    for a, b in zip(off, gated):
        for key in (("body", "pos"), ("body", "quat"), ("control", "ff"), ("control", "cmd")):
            assert torch.equal(a[key], b[key]), key
    assert bool(off[-1]["control", "ff"].abs().min() > 0)  # the residual did act


def _tilted(state: TensorDict, roll_deg: float) -> TensorDict:
    """``state`` rolled by ``roll_deg``, in the body and in the attitude measurement alike."""
    state = state.clone()
    roll = torch.full_like(state["ref", "yaw"], math.radians(roll_deg))
    state["body", "quat"] = quat_from_euler(roll, torch.zeros_like(roll), state["ref", "yaw"]).squeeze(-2)
    state["sensors", MEAS_KEY, "attitude"] = torch.cat((roll, torch.zeros_like(roll), state["ref", "yaw"]), -1)
    return state


@pytest.mark.parametrize("feedback", ["truth", "estimate"])
@pytest.mark.parametrize("case", ["calm", "tilt", "thrust", "height"])
def test_a_state_near_a_limit_zeroes_the_residual_that_step_and_a_calm_one_does_not(case, feedback):
    cfg = with_monitor(quiet_config(controller=replace(EnvConfig().controller, feedback=feedback)), MonitorConfig())
    sim, params, state = _hover(cfg)
    state = state.clone()  # with true-state feedback the navigation position is the body's tensor
    limit = cfg.controller.max_tilt_deg + cfg.residual.monitor.tilt_margin_deg  # 40 deg
    if case == "calm":  # just inside every limit
        state = _tilted(state, limit - 1.0)
    elif case == "tilt":
        state = _tilted(state, limit + 1.0)
    elif case == "thrust":  # the PD at the rotors' collective limit
        state["control", "pd_wrench"][..., 0] = VehicleParams.from_config(cfg.vehicle).collective_limit
    else:  # the autopilot 6 m below the reference (the threshold is 5 m)
        state["nav", "pos"][..., 2] -= 6.0
    new = sim.step(params, state, PUSH)
    hold = round(cfg.residual.monitor.hold_s / cfg.timing.control_dt_s)
    if case == "calm":
        assert bool((new["control", "ff"] != 0).all()) and int(new["control", "monitor_left"]) == 0
    else:
        assert torch.equal(new["control", "ff"], torch.zeros(1, 4)) and int(new["control", "monitor_left"]) == hold + 1
        # what is applied is the PD alone
        assert torch.equal(new["control", "cmd"], state["control", "pd_wrench"])


def test_the_hold_keeps_pd_alone_then_the_residual_returns_at_the_slew_limit():
    monitor = MonitorConfig(height_below_ref_m=None, hold_s=0.2)
    cfg = with_monitor(quiet_config(), monitor)
    hold = round(monitor.hold_s / cfg.timing.control_dt_s)
    assert hold == 20
    sim, params, state = _hover(cfg)
    flown = _fly(sim, params, _tilted(state, 60.0), 150)  # far past the limit: the PD rights it
    left = torch.stack([s["control", "monitor_left"][0, 0] for s in flown])
    ff = torch.stack([s["control", "ff"][0] for s in flown])
    near = (left == hold + 1).nonzero().squeeze(-1)
    last = int(near[-1])  # the last step near a limit
    assert 0 < last < 100 and bool((left[: last + 1] > 0).all())
    # PD alone for exactly `hold` steps after it, counting down
    assert torch.equal(left[last + 1: last + hold + 1], torch.arange(hold, 0, -1))
    assert torch.equal(ff[: last + hold + 1], torch.zeros(last + hold + 1, 4))
    # then the residual comes back from zero, no faster than the slew limit, and keeps coming
    after = ff[last + hold:]
    assert bool((left[last + hold + 1:] == 0).all())
    slew = torch.tensor(ResidualConfig().slew_limit_per_step)
    assert bool(((after[1:] - after[:-1]).abs() <= slew + 1e-5).all())  # float32 rounding of ff near 10 N
    assert torch.allclose(after[1].abs(), slew) and bool((after[-1] != 0).all())


def test_a_partial_reset_clears_the_monitor_of_the_restarted_rows_only():
    env = QuadWindEnv(with_monitor(quiet_config(), MonitorConfig()), batch_size=[3])
    check_env_specs(env)
    sc = make_scenarios(3, traj_id="hover", altitude_m=30.0, start_step=-1, wind_speed_ref_m_s=0.0, turb_intensity=0.0)
    td = env.reset(scenario=sc)
    assert not bool(td[MONITOR_KEY].any())
    env.state["control", "monitor_left"] = torch.tensor([[7], [5], [0]])
    td = env.reset(TensorDict(_reset=torch.tensor([[True], [False], [False]]), batch_size=[3]), scenario=sc)
    assert env.state["control", "monitor_left"].squeeze(-1).tolist() == [0, 5, 0]
    td["action"] = torch.zeros(3, 4)
    td = env.step(td)["next"]  # calm hover: the held row counts down, the others stay clear
    assert env.state["control", "monitor_left"].squeeze(-1).tolist() == [0, 4, 0]
    assert td[MONITOR_KEY].squeeze(-1).tolist() == [False, True, False]


def test_monitor_authority_counts_the_scored_samples_only():
    # episode 0: samples at steps 10..40, the pattern starts at 15, the last sample after its end;
    # episode 1: all scored
    log = TensorDict(step=torch.tensor([[10, 20, 30, 40], [10, 20, 30, 40]]).unsqueeze(-1),
                     valid=torch.tensor([[True, True, True, False], [True, True, True, True]]),
                     batch_size=[2, 4])
    log[MONITOR_KEY] = torch.tensor([[True, True, False, True], [False, False, False, True]]).unsqueeze(-1)
    res = FlightResults(torch.arange(2), torch.ones(2), torch.ones(2), torch.zeros(2, dtype=torch.bool), log)
    share = monitor_authority(res, torch.tensor([15, 0]))
    assert share == {"monitor_active_fraction": 2 / 6, "monitor_active_fraction_max": 1 / 2}


@pytest.mark.slow  # flies a policy and PD (2 episodes, 5 s quick patterns, eager): 15-18 s on a busy 2-core machine
def test_validate_policy_recipe_flies_the_policy_and_pd_with_the_monitor(tmp_path, monkeypatch, capsys):
    path = ROOT / "recipes" / "validate_policy.py"
    spec = importlib.util.spec_from_file_location("validate_policy_recipe", path)
    recipe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(recipe)
    out = tmp_path / "val.json"
    monkeypatch.setattr(sys, "argv", [str(path), "--policy", str(ROOT / "quadwind_trl/checkpoints/policy_horizontal.pt"),
                                      "--monitor", "--episodes", "2", "--quick", "--eager", "--no-progress", "--out", str(out)])
    recipe.main()
    result = json.loads(out.read_text())
    m = result["metrics"]
    two = FlightResults(torch.arange(2), torch.ones(2), torch.ones(2), torch.zeros(2, dtype=torch.bool),
                        TensorDict({}, batch_size=[2, 0]))
    assert set(paired_metrics(two, two)) <= set(m)  # the trainer's evaluation metrics, all of them
    assert m["episodes"] == 2 and 0.0 <= m["monitor_active_fraction"] <= m["monitor_active_fraction_max"] <= 1.0
    assert result["monitor"] == config_to_dict(MonitorConfig()) and result["quick"] and result["episodes"] == 2
    assert {"command", "git_commit", "platform"} <= set(result)
    assert "with the runtime monitor" in capsys.readouterr().out


def test_ablation_flies_and_replays_the_monitor_it_records():
    """``sweep_setup(..., monitor)`` switches the monitor on over the quick flights' change, and a
    results file's recorded monitor is what its re-flight uses (``replay.flown_monitor``)."""
    from quadwind_trl.config import EnvConfig, MonitorConfig, config_to_dict
    from quadwind_trl.evaluation.replay import flown_monitor
    from quadwind_trl.evaluation.tracking import sweep_setup
    from quadwind_trl.quick import SWEEP_QUICK
    from quadwind_trl.regimes import SWEEPS

    monitor = MonitorConfig(hold_s=2.0)
    _, override = sweep_setup(SWEEPS["ood"], quick=True, monitor=monitor)
    _, quick_only = sweep_setup(SWEEPS["ood"], quick=True)
    cfg = override(EnvConfig())
    assert cfg.residual.monitor == monitor and quick_only(EnvConfig()).residual.monitor is None
    assert cfg.timing == SWEEP_QUICK.config(EnvConfig()).timing and cfg.trajectories == quick_only(EnvConfig()).trajectories
    assert sweep_setup(SWEEPS["ood"])[1] is None  # the sweep as designed: no change
    assert flown_monitor({"monitor": config_to_dict(monitor)}) == monitor
    assert flown_monitor({}) is None and flown_monitor({"monitor": None}) is None
