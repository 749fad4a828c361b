"""The learning levers a user switches on by name (``RLEnvSpec.base_state_inputs``,
``preview_inputs``, ``privileged_inputs``, ``memory_frames``): each validated at the boundary, computed from what it
names, off by default (the stack and the policy as before), recorded in the policy file, and
rebuilt when the policy is loaded; the privileged inputs never reach the actor nor any flight."""
from __future__ import annotations

import json
import math
from dataclasses import asdict, replace
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict

from quadwind_trl.config import GRAVITY_M_S2
from quadwind_trl.envs.runner import fly
from quadwind_trl.estimator import untrained_estimator
from quadwind_trl.keys import (BASE_STATE_CHANNELS, OBSERVATION_CHANNELS, OBSERVATION_DIM, PREVIEW_CHANNELS,
                               PRIVILEGED_CHANNELS)
from quadwind_trl.manifest import CHECKPOINT_DIR
from quadwind_trl.rl.cli import build_parser, run, with_base_controller
from quadwind_trl.rl.config import PPOConfig
from quadwind_trl.rl.envs import RLEnvSpec, make_env, policy_env_settings, vecnorm, vecnorm_state_dict
from quadwind_trl.rl.paired import validation_scenarios
from quadwind_trl.rl.envs import EnvFactory
from quadwind_trl.rl.policy import build_actor_critic, check_recurrent, load_policy, network_dims, spec_to_dict
from quadwind_trl.rl.trainer import PPOTrainer, ResumeMismatch, check_same_env
from quadwind_trl.transforms import ObservationStack, PolicyObservation, PrivilegedObservation, ReferenceAhead
from torchrl.collectors import Collector
from torchrl.envs.utils import ExplorationType
from torchrl.modules import GRUModule, set_recurrent_mode
from quadwind_trl.transforms.observation import base_state_channels, to_heading_frame

from test_ppo import hover_spec
from test_transforms import scenarios, short_config

AWARE = CHECKPOINT_DIR / "policy_horizontal.pt"
BASE_INDEX = slice(OBSERVATION_DIM, None)


def base_config(name: str):
    """The short test flights flown on the classical base law ``name`` (``"pd"``: the paper's)."""
    return with_base_controller("horizontal", short_config(), name)


@pytest.fixture(scope="module")
def bundle():
    return untrained_estimator("horizontal", seed=0, config=short_config())


def _flight(bundle, base: str, steps: int, action: float = 0.0, hold: int = 1, **settings):
    """The env of ``settings`` on base law ``base`` deciding every ``hold`` control steps, flown
    ``steps`` env steps of the same 3 episodes under a constant ``action``: (env, [3, steps + 1]
    tensordict of what each step returned)."""
    config, base_wind = base_config(base)
    config = replace(config, timing=replace(config.timing, hold_control_steps=hold))
    env = make_env("horizontal", bundle, 3, config=config, base_wind_input=base_wind, compile_step=False, **settings)
    td = env.reset(scenario=scenarios(3, start_step=[-1] * 3))  # airborne at the pattern: the base laws' states move
    rows = [td.clone()]
    for _ in range(steps):
        td["action"] = torch.full((3, 4), action)
        td = env.step(td)["next"]
        rows.append(td.select(*rows[0].keys(True, True)).clone())
    return env, torch.stack(rows, 1)


# --- boundaries -----------------------------------------------------------------------------------

def test_bad_lever_settings_are_refused_naming_the_field_and_the_allowed_names():
    dob, dob_wind = base_config("dob")
    for settings, why in (
        ({"base_state_inputs": ("nope",)}, r"RLEnvSpec\.base_state_inputs=\('nope',\): unknown \['nope'\]; allowed: "
                                           r"the groups \['ff', 'force', 'thrust'\]"),
        ({"base_state_inputs": ("integral",)}, r"base_state_inputs=\('integral',\): \['integral'\] not available here; "
                                               r"allowed: the groups \['ff', 'force', 'thrust'\] or the channels "
                                               r"\('base_force_fwd'"),
        ({"base_state_inputs": ("mean_wind_fwd",)}, r"base_state_inputs=.*\['mean_wind_fwd'\] are privileged .* "
                                                    r"allowed for the critic only, in privileged_inputs"),
        ({"privileged_inputs": ("force",)}, r"RLEnvSpec\.privileged_inputs=\('force',\): unknown \['force'\]; allowed: "
                                            r"the groups \['mean_wind', 'true_error', 'true_vel_error', 'turbulence'\]"),
        ({"preview_inputs": ("ahead_3s",)}, r"RLEnvSpec\.preview_inputs=\('ahead_3s',\): unknown \['ahead_3s'\]; "
                                            r"allowed: the groups \['ahead_0\.5s', 'ahead_1s', 'ahead_2s'\]"),
        ({"preview_inputs": ("true_error",)}, r"RLEnvSpec\.preview_inputs=\('true_error',\): unknown \['true_error'\]"),
        ({"memory_frames": 0}, r"RLEnvSpec\.memory_frames=0; allowed: a whole number >= 1"),
        ({"memory_frames": 2.0}, r"RLEnvSpec\.memory_frames=2\.0; allowed: a whole number >= 1"),
    ):
        with pytest.raises(ValueError, match=why):
            RLEnvSpec(config=dob, base_wind_input=dob_wind, **settings)
    # the paper's PD keeps no state: nothing to read
    with pytest.raises(ValueError, match=r"\['force'\] not available here; allowed: the groups \[\] or the channels \(\)"):
        RLEnvSpec(base_state_inputs=("force",))
    with pytest.raises(ValueError, match=r"ObservationStack\(frames=0\); allowed: a whole number >= 1"):
        ObservationStack(0)
    with pytest.raises(ValueError, match=r"PolicyObservation\(preview_channels=\('ahead_1s',\)\): \['ahead_1s'\] unknown"):
        PolicyObservation(preview_channels=("ahead_1s",))  # the transform takes channels; groups are the spec's
    with pytest.raises(ValueError, match=r"ReferenceAhead\(control_dt_s=0\); allowed: > 0 s"):
        ReferenceAhead(0)


def test_each_base_law_offers_the_channels_of_its_state():
    assert base_state_channels(base_config("pd")[0]) == ()
    assert base_state_channels(base_config("pd_ff")[0]) == ()  # the feed-forward law keeps no state
    groups = {name: {c.rsplit("_", 1)[0] if c != "base_thrust_over_weight" else c for c in base_state_channels(base_config(name)[0])}
              for name in ("pid", "dob", "l1")}
    assert groups == {"pid": {"base_int", "base_ff"}, "dob": {"base_force", "base_thrust_over_weight", "base_ff"},
                      "l1": {"base_force", "base_thrust_over_weight", "base_vel_err", "base_ff"}}
    # groups expand to their channels, in catalogue order whatever the order named
    config, wind = base_config("dob")
    spec = RLEnvSpec(config=config, base_wind_input=wind, base_state_inputs=("ff", "base_force_U"))
    assert spec.base_state_inputs == ("base_force_U", "base_ff_fwd", "base_ff_left", "base_ff_U")
    assert spec.observation_channels == OBSERVATION_CHANNELS + spec.base_state_inputs
    # "all": every channel the base has; refused where it has none
    assert RLEnvSpec(config=config, base_wind_input=wind, base_state_inputs=("all",)).base_state_inputs == \
        base_state_channels(config)
    with pytest.raises(ValueError, match=r"base_state_inputs=\('all',\): this base controller keeps no state"):
        RLEnvSpec(base_state_inputs=("all",))


def test_the_ppo_recipes_refuse_bad_levers_before_any_output(tmp_path):
    for flags, why in ((["--base-state-inputs", "integral"], r"error: RLEnvSpec\.base_state_inputs=\('integral',\): "
                                                             r"\['integral'\] not available here"),
                       (["--base-state-inputs", "turbulence"], r"error: RLEnvSpec\.base_state_inputs=.* are privileged"),
                       (["--preview-inputs", "ahead_3s"], r"error: RLEnvSpec\.preview_inputs=\('ahead_3s',\): unknown"),
                       (["--memory-frames", "0"], r"error: RLEnvSpec\.memory_frames=0")):
        args = build_parser("horizontal", "").parse_args(["--quick", "--base-controller", "dob", *flags,
                                                          "--out", str(tmp_path / "run")])
        with pytest.raises(SystemExit, match=why):
            run("horizontal", args)
        assert not (tmp_path / "run").exists()


# --- off by default -------------------------------------------------------------------------------

def test_the_levers_off_leave_the_stack_and_the_networks_as_before(bundle):
    plain = make_env("horizontal", bundle, 1, config=short_config(), compile_step=False)
    assert not any(isinstance(t, (ObservationStack, PrivilegedObservation, ReferenceAhead)) for t in plain.transform)
    assert plain.observation_spec["observation"].shape[-1] == OBSERVATION_DIM
    assert "ref_ahead" not in plain.observation_spec.keys()
    assert network_dims(RLEnvSpec()) == {"obs_dim": OBSERVATION_DIM, "privileged_dim": 0, "recurrent_hidden": 0,
                                         "action_dim": 4}
    actor, value = build_actor_critic(PPOConfig(hidden=(8, 8)))
    assert value.in_keys == ["observation"] and list(value.state_dict()) == ["module.0.weight", "module.0.bias",
                                                                              "module.2.weight", "module.2.bias",
                                                                              "module.4.weight", "module.4.bias"]


def test_an_old_policy_file_rebuilds_the_paper_actor_and_flies_as_before():
    payload = torch.load(AWARE, weights_only=True)
    assert "base_state_inputs" not in payload["env_spec"] and "memory_frames" not in payload["env_spec"]
    settings = policy_env_settings(payload["env_spec"], None)
    assert settings["base_state_inputs"] == () and settings["preview_inputs"] == () and settings["memory_frames"] == 1
    actor, loaded = load_policy(AWARE)
    assert actor.module[0].module[0][0].in_features == OBSERVATION_DIM
    state = actor.state_dict()
    assert all(torch.equal(state[k], v) for k, v in payload["policy"].items())
    # the env it flies in is the paper's stack: 23 inputs, no stack, no privileged entry
    env = make_env("horizontal", untrained_estimator("horizontal", config=short_config()), 1, config=short_config(),
                   vecnorm_state=loaded["vecnorm"], compile_step=False,
                   **{k: v for k, v in settings.items() if k != "base_wind_input"})
    assert env.observation_spec["observation"].shape[-1] == OBSERVATION_DIM
    assert not any(isinstance(t, (ObservationStack, PrivilegedObservation)) for t in env.transform)


# --- what each lever computes ---------------------------------------------------------------------

def test_the_stack_with_every_lever_passes_torchrls_spec_check():
    from torchrl.envs.utils import check_env_specs

    config, base_wind = base_config("l1")
    env = make_env("horizontal", None, 3, wind_input="truth", config=config, base_wind_input=base_wind,
                   base_state_inputs=("all",), preview_inputs=("ahead_1s",), privileged_inputs=("mean_wind", "true_vel_error"),
                   memory_frames=2, recurrent_hidden=8, compile_step=False)
    check_env_specs(env)
    spec = env.observation_spec
    assert spec["observation"].shape[-1] == 2 * (OBSERVATION_DIM + len(base_state_channels(config)) + 3)
    assert spec["privileged"].shape[-1] == 6 and spec["recurrent_state"].shape[-2:] == (1, 8)


@pytest.mark.parametrize("base", ["dob", "pid", "l1"])
def test_base_state_channels_are_the_base_laws_state_and_action_zero_is_still_the_base_law(bundle, base):
    channels = base_state_channels(base_config(base)[0])
    env, with_state = _flight(bundle, base, 8, base_state_inputs=channels, obs_clip=None)
    _, plain = _flight(bundle, base, 8, obs_clip=None)
    # the physics and the 23 inputs are untouched, bit for bit
    assert torch.equal(with_state["truth", "pos"], plain["truth", "pos"])
    assert torch.equal(with_state["cmd_wrench"], plain["cmd_wrench"])
    # the base channels, before normalisation, against the env's base state by hand
    raw = PolicyObservation(base_config(base)[0], base_channels=channels)._call(with_state[:, -1].clone())["observation"]
    state = with_state[:, -1]["base"]
    yaw = with_state[:, -1]["meas", "attitude"][..., 2:3]
    expect = {}
    mass = base_config(base)[0].vehicle.mass_kg
    ff = torch.zeros(3, 3)
    if "force_hat" in state.keys():
        f = state["force_hat"]
        fwd, left = to_heading_frame(f[..., :1], f[..., 1:2], yaw)
        expect.update(base_force_fwd=fwd, base_force_left=left, base_force_U=f[..., 2:],
                      base_thrust_over_weight=state["thrust_hat"] / (mass * GRAVITY_M_S2))
        ff = ff - f / mass
    if "integral" in state.keys():
        i = state["integral"]
        fwd, left = to_heading_frame(i[..., :1], i[..., 1:2], yaw)
        expect.update(base_int_fwd=fwd, base_int_left=left, base_int_U=i[..., 2:])
        ff = ff - torch.tensor(base_config(base)[0].controller.ki_pos) * i
    if "vel_hat" in state.keys():
        v = state["vel_hat"] - with_state[:, -1]["nav_vel"]
        fwd, left = to_heading_frame(v[..., :1], v[..., 1:2], yaw)
        expect.update(base_vel_err_fwd=fwd, base_vel_err_left=left, base_vel_err_U=v[..., 2:])
    fwd, left = to_heading_frame(ff[..., :1], ff[..., 1:2], yaw)
    expect.update(base_ff_fwd=fwd, base_ff_left=left, base_ff_U=ff[..., 2:])
    assert set(expect) == set(channels)
    for i, name in enumerate(channels):
        torch.testing.assert_close(raw[:, OBSERVATION_DIM + i:OBSERVATION_DIM + i + 1], expect[name], msg=name)
    assert raw[:, BASE_INDEX].ne(0).any(0).all()  # every channel has moved after 8 control steps of flight


def test_the_reference_ahead_is_where_the_reference_will_be_from_the_vehicle_and_restarts_with_each_episode(bundle):
    # decisions of 0.1 s: the horizons 0.5, 1 and 2 s are 5, 10 and 20 decisions ahead
    env, flown = _flight(bundle, "dob", 24, hold=10, preview_inputs=PREVIEW_CHANNELS, obs_clip=None)
    _, plain = _flight(bundle, "dob", 24, hold=10, obs_clip=None)
    assert torch.equal(flown["truth", "pos"], plain["truth", "pos"])  # the physics untouched, bit for bit
    assert torch.equal(flown["observation"][..., :OBSERVATION_DIM], plain["observation"])  # the 23 inputs too
    ahead, ref, nav = flown["ref_ahead"], flown["ref_pos"], flown["nav_pos"]  # [3, 25, 3, 3], [3, 25, 3]
    for k, decisions in enumerate((5, 10, 20)):
        torch.testing.assert_close(ahead[:, :25 - decisions, k], ref[:, decisions:] - nav[:, :25 - decisions])
    assert (ahead[:, :, 2].norm(dim=-1).amax(1) > 10).all()  # metres ahead as the pattern speeds up, not a rounding
    # the observation's channels: the same vectors in the heading frame of the measured yaw
    last = flown[:, -1]
    raw = PolicyObservation(base_config("dob")[0], preview_channels=PREVIEW_CHANNELS)._call(last.clone())["observation"]
    yaw = last["meas", "attitude"][..., 2:3]
    for k in range(3):
        vec = last["ref_ahead"][:, k]
        fwd, left = to_heading_frame(vec[..., :1], vec[..., 1:2], yaw)
        torch.testing.assert_close(raw[:, OBSERVATION_DIM + 3 * k:OBSERVATION_DIM + 3 * k + 3],
                                   torch.cat((fwd, left, vec[..., 2:]), -1))
    # past the trajectory's end the reference holds its last sample, as the flown reference does
    base = env.base_env
    end = base.params["end_step"]
    torch.testing.assert_close(base.reference_at(end + 500).pos, base.reference_at(end + 1).pos)
    # a row that restarts reads its new episode's trajectory at once
    first = env.reset()
    td = env.reset(first.clone().set("_reset", torch.tensor([[False], [True], [False]])),
                   scenario=scenarios(3, traj=("figure8_h", "hover", "racetrack_h"), start_step=[-1] * 3))
    new = base.reference_at(base.state["step"] + 10).pos - td["nav_pos"]
    torch.testing.assert_close(td["ref_ahead"][1, 1], new[1])
    assert not torch.equal(td["ref_ahead"][1], first["ref_ahead"][1])
    assert torch.equal(td["ref_ahead"][[0, 2]], first["ref_ahead"][[0, 2]])  # the others fly on


def test_privileged_channels_are_the_truth_and_only_the_training_env_computes_them(bundle):
    env, flown = _flight(bundle, "pd", 5, privileged_inputs=("mean_wind", "turbulence", "true_error", "true_vel_error"))
    assert env.observation_spec["privileged"].shape[-1] == len(PRIVILEGED_CHANNELS)
    last = flown[:, -1]
    raw = PrivilegedObservation(PRIVILEGED_CHANNELS)._call(last.clone())["privileged"]
    yaw = last["meas", "attitude"][..., 2:3]
    for i, vec in enumerate((last["truth", "mean_wind"], last["truth", "wind"] - last["truth", "mean_wind"],
                             last["truth", "pos"] - last["ref_pos"], last["truth", "vel"] - last["ref_vel"])):
        fwd, left = to_heading_frame(vec[..., :1], vec[..., 1:2], yaw)
        torch.testing.assert_close(raw[:, 3 * i:3 * i + 3], torch.cat((fwd, left, vec[..., 2:]), -1))
    # normalised on its own: the policy's observation normalisation is the same as without it
    _, plain = _flight(bundle, "pd", 5)
    assert torch.equal(flown["observation"], plain["observation"])
    assert set(vecnorm(env, "privileged").in_keys) == {"privileged"}


def test_the_critics_privileged_inputs_in_a_collected_batch_are_the_normalised_ones_now_and_next_across_resets():
    """What GAE reads: at every step the critic's ``("next", "privileged")`` is the ``privileged``
    the next step starts from, except where an episode ended (the next step is then a new
    episode's first); both are the training normalisation's output, clipped."""
    spec = replace(hover_spec(duration_s=1.0), num_envs=4, privileged_inputs=("mean_wind", "turbulence", "true_error",
                                                                           "true_vel_error"), desync_steps=6)
    env = EnvFactory(spec)()
    torch.manual_seed(0)
    actor, value = build_actor_critic(PPOConfig(hidden=(8, 8)), **network_dims(spec))
    collector = Collector(env, actor, frames_per_batch=4 * 24, total_frames=-1, exploration_type=ExplorationType.RANDOM,
                          auto_register_policy_transforms=False)
    batch = next(iter(collector)).reshape(4, 24)
    collector.shutdown()
    now, nxt = batch["privileged"], batch["next", "privileged"]
    ended = batch["next", "done"].squeeze(-1)[:, :-1]
    assert ended.any() and (~ended).any()  # partial resets happened in the batch
    assert torch.equal(now[:, 1:][~ended], nxt[:, :-1][~ended])
    assert not (now[:, 1:][ended] == nxt[:, :-1][ended]).all(-1).any()
    assert now.abs().max() <= spec.obs_clip and nxt.abs().max() <= spec.obs_clip
    # the statistics learn during collection from every observation the critic reads: the first
    # reset's, each step's and each restarting row's first
    count = vecnorm_state_dict(env, "privileged")["_extra_state"]["count.-|-.privileged"]
    assert int(count) == 4 + 4 * 24 + int(batch["next", "done"].sum())


def test_the_stack_holds_the_last_k_decisions_across_holds_and_resets_only_the_rows_that_restart(bundle):
    k = 3
    # one frame per decision (env step), whatever the control steps held under it
    env, stacked = _flight(bundle, "pd", 6, action=0.1, hold=5, memory_frames=k)
    _, plain = _flight(bundle, "pd", 6, action=0.1, hold=5)
    frames = stacked["observation"].unflatten(-1, (k, OBSERVATION_DIM))
    single = plain["observation"]
    for t in range(stacked.shape[1]):
        for j in range(k):  # frame j of step t is step t - (k - 1 - j), the first repeated before it
            assert torch.equal(frames[:, t, j], single[:, max(0, t - (k - 1 - j))]), (t, j)
    # a partial reset restarts the masked row's stack with its first observation, and leaves the others
    td = stacked[:, -1].clone()
    td["_reset"] = torch.tensor([[False], [True], [False]])
    before = env.transform[[isinstance(t, ObservationStack) for t in env.transform].index(True)]._stack.clone()
    out = env.reset(td)
    now = out["observation"].unflatten(-1, (k, OBSERVATION_DIM))
    assert torch.equal(now[0].flatten(), before[0].flatten()) and torch.equal(now[2].flatten(), before[2].flatten())
    assert torch.equal(now[1], now[1, :1].expand(k, OBSERVATION_DIM))
    assert not torch.equal(now[1], before[1])


def test_the_stack_resets_masked_rows_of_a_batch_of_any_shape_with_no_host_sync():
    stack = ObservationStack(2)
    first = TensorDict({"observation": torch.arange(12.0).reshape(2, 3, 2)}, [2, 3])
    stack._reset(TensorDict({}, [2, 3]), first.clone())
    step = TensorDict({"observation": 100 + torch.arange(12.0).reshape(2, 3, 2)}, [2, 3])
    out = stack._call(step.clone())["observation"]
    assert torch.equal(out, torch.cat((first["observation"], step["observation"]), -1))
    mask = torch.tensor([[True, False, False], [False, False, True]]).unsqueeze(-1)
    again = TensorDict({"observation": -torch.ones(2, 3, 2)}, [2, 3])
    out = stack._reset(TensorDict({"_reset": mask}, [2, 3]), again.clone())["observation"]
    assert torch.equal(out[mask.squeeze(-1)], -torch.ones(2, 4))
    assert torch.equal(out[~mask.squeeze(-1)], torch.cat((first["observation"], step["observation"]), -1)[~mask.squeeze(-1)])
    # the masked reset is a select over the batch: under a sync-checking mode it never asks the host
    if torch.cuda.is_available():
        stack.to("cuda")
        td = TensorDict({"observation": torch.ones(2, 3, 2, device="cuda")}, [2, 3], device="cuda")
        stack._reset(TensorDict({}, [2, 3], device="cuda"), td.clone())
        torch.cuda.set_sync_debug_mode("error")
        try:
            stack._reset(TensorDict({"_reset": mask.cuda()}, [2, 3], device="cuda"), td.clone())
            stack._call(td.clone())
        finally:
            torch.cuda.set_sync_debug_mode("default")


def test_a_recurrent_actor_carries_its_hidden_state_restarts_it_with_each_episode_and_replays_it_as_sequences():
    spec = replace(hover_spec(duration_s=1.0), recurrent_hidden=16, num_envs=4)
    env = EnvFactory(spec)(desync_steps=5)  # short first episodes: resets inside the batch
    torch.manual_seed(0)
    actor, _ = build_actor_critic(PPOConfig(hidden=(32, 32)), recurrent_hidden=16)
    collector = Collector(env, actor, frames_per_batch=4 * 40, total_frames=-1, exploration_type=ExplorationType.RANDOM,
                          auto_register_policy_transforms=False)
    data = next(iter(collector))
    collector.shutdown()
    init = data["is_init"].squeeze(-1)
    assert init[:, 0].all() and init[:, 1:].any()  # episodes restarted within the rows
    assert data["recurrent_state"][init].eq(0).all()  # every episode starts from a zero hidden state
    carried = ~init[:, 1:]
    assert torch.equal(data["recurrent_state"][:, 1:][carried], data["next", "recurrent_state"][:, :-1][carried])
    assert data["recurrent_state"][:, 1:][carried].ne(0).any()
    # the update's sequences ([rows, T] in recurrent mode) give the log-probs the collection drew with
    with set_recurrent_mode(True):
        log_prob = actor.get_dist(data.select("observation", "recurrent_state", "is_init").clone()).log_prob(data["action"])
    torch.testing.assert_close(log_prob, data["action_log_prob"], atol=1e-4, rtol=1e-4)


def test_a_recurrent_actor_refuses_the_ppo_settings_it_cannot_train_with():
    spec = replace(hover_spec(), recurrent_hidden=8)
    check_recurrent(PPOConfig(), spec)  # 512 = 2 whole rows of 256 steps
    with pytest.raises(ValueError, match=r"RLEnvSpec\.recurrent_hidden=8: PPOConfig\.minibatch=512 must be a multiple "
                                         r"of steps_per_env=384"):
        check_recurrent(PPOConfig(steps_per_env=384, num_envs=64), spec)
    with pytest.raises(ValueError, match=r"PPOConfig\.collect_workers=2, collector='local'; allowed with a recurrent "
                                         r"actor: collect_workers=1"):
        check_recurrent(PPOConfig(collect_workers=2), spec)
    with pytest.raises(ValueError, match=r"RLEnvSpec\.recurrent_hidden=-1; allowed: a whole number >= 0"):
        replace(spec, recurrent_hidden=-1)
    check_recurrent(PPOConfig(collect_workers=2), hover_spec())  # no recurrent actor: nothing to refuse


# --- trained, saved, loaded and flown -------------------------------------------------------------

def test_a_policy_with_every_lever_trains_records_them_loads_the_same_actor_and_flies_without_privileged(tmp_path):
    config, base_wind = with_base_controller("horizontal", hover_spec().env_config, "dob")
    spec = replace(hover_spec(duration_s=1.0), config=config, base_wind_input=base_wind, base_state_inputs=("force", "ff"),
                   preview_inputs=("ahead_2s",), privileged_inputs=("mean_wind", "turbulence", "true_error"),
                   memory_frames=3, recurrent_hidden=16)
    cfg = PPOConfig(total_frames=2 * 4 * 16, num_envs=4, steps_per_env=16, epochs=1, minibatch=32, hidden=(32, 32),
                    eval_every_frames=0, checkpoint_every_frames=1)
    out = tmp_path / "run"
    sc = validation_scenarios("horizontal", 1)
    sc.update({"traj_id": torch.tensor([9]), "altitude_m": torch.tensor([10.0]), "start_step": torch.tensor([-1])})
    PPOTrainer(spec, cfg, out, eval_scenarios=sc, progress=False).train()
    manifest = json.loads((out / "policy.json").read_text())
    assert manifest["env_spec"]["base_state_inputs"] == list(spec.base_state_inputs)
    assert manifest["env_spec"]["preview_inputs"] == ["ahead_2s_fwd", "ahead_2s_left", "ahead_2s_U"]
    assert manifest["env_spec"]["privileged_inputs"] == list(spec.privileged_inputs)
    assert manifest["env_spec"]["memory_frames"] == 3 and manifest["env_spec"]["recurrent_hidden"] == 16
    assert manifest["observation_channels"] == list(OBSERVATION_CHANNELS + spec.base_state_inputs + spec.preview_inputs)
    latest = torch.load(out / "checkpoints" / "latest.pt", weights_only=True)
    assert "privileged_vecnorm" in latest  # a resume needs the critic's normalisation ...
    saved = torch.load(out / "policy.pt", weights_only=True)
    assert "privileged_vecnorm" not in saved  # ... a policy never
    assert saved["value"]["module.mlp.0.weight"].shape[-1] == 3 * (OBSERVATION_DIM + 6 + 3) + 9  # the critic read it
    # the loaded actor is the saved one: a GRU of 16 units on (23 + 6 + 3) x 3 inputs
    actor, payload = load_policy(out / "policy.pt")
    gru = next(m for m in actor.modules() if isinstance(m, GRUModule))
    assert (gru.gru.input_size, gru.gru.hidden_size) == (3 * (OBSERVATION_DIM + 6 + 3), 16)
    assert actor.state_dict().keys() == saved["policy"].keys()
    assert all(torch.equal(actor.state_dict()[k], v) for k, v in saved["policy"].items())
    # the evaluation path: the env of the policy's flight settings has no privileged entry, and flies
    settings = policy_env_settings(payload["env_spec"], None)
    assert "privileged_inputs" not in settings
    env = make_env("horizontal", untrained_estimator("horizontal"), 1, config=spec.config, vecnorm_state=payload["vecnorm"],
                   compile_step=False, **settings)
    assert "privileged" not in env.observation_spec.keys(True, True)
    assert not any(isinstance(t, PrivilegedObservation) for t in env.transform)
    result = fly(env, sc, policy=actor)
    assert torch.isfinite(result.rmse).all() and torch.isfinite(result.rmse_xy).all()
    # and the ablation's flights of it (the residual and its base alone), as every later evaluation flies it
    from quadwind_trl.evaluation.ablation import fly_controllers

    flown = fly_controllers("horizontal", sc, out / "policy.pt", untrained_estimator("horizontal"), ("pd", "aware", "pid"),
                            log_keys=("step",))
    assert torch.equal(flown["aware"].rmse_xy, result.rmse_xy)  # the same flight
    assert not torch.equal(flown["aware"].rmse_xy, flown["pd"].rmse_xy)
    # a classical row beside it flies its own law, whose state lacks the observer's force channels
    assert torch.isfinite(flown["pid"].rmse_xy).all() and not torch.equal(flown["pid"].rmse_xy, flown["pd"].rmse_xy)
    # a resume must give the critic the same inputs
    with pytest.raises(ResumeMismatch, match=r"RLEnvSpec\.privileged_inputs=\(\) but the checkpoint's run used"):
        check_same_env(payload["env_spec"], replace(spec, privileged_inputs=()), None)
    with pytest.raises(ResumeMismatch, match=r"RLEnvSpec\.memory_frames=1 but the checkpoint's run used 3"):
        check_same_env(payload["env_spec"], replace(spec, memory_frames=1), None)
    with pytest.raises(ResumeMismatch, match=r"RLEnvSpec\.recurrent_hidden=0 but the checkpoint's run used 16"):
        check_same_env(payload["env_spec"], replace(spec, recurrent_hidden=0), None)
    check_same_env(spec_to_dict(spec), spec, None)
    assert math.isfinite(manifest["wall_time_s"])


def test_the_privileged_critic_is_the_plain_one_reading_more_and_leaves_the_actor_and_random_stream_as_they_were():
    cfg = PPOConfig(hidden=(16, 16), seed=3)
    torch.manual_seed(3)
    plain_actor, plain_value = build_actor_critic(cfg)
    plain_next = torch.rand(8)  # what the first rollout's exploration would draw next
    torch.manual_seed(3)
    actor, value = build_actor_critic(cfg, privileged_dim=12)
    assert torch.equal(torch.rand(8), plain_next)
    assert all(torch.equal(a, b) for a, b in zip(actor.state_dict().values(), plain_actor.state_dict().values()))
    wide, plain = value.module.mlp, plain_value.module
    assert torch.equal(wide[0].weight[:, :OBSERVATION_DIM], plain[0].weight) and torch.equal(wide[0].bias, plain[0].bias)
    assert all(torch.equal(a, b) for a, b in zip(wide[1:].parameters(), plain[1:].parameters()))
    # the privileged columns: orthogonal with the layer's gain, drawn from their own seeded stream
    extra = wide[0].weight[:, OBSERVATION_DIM:]
    assert torch.allclose(extra.T @ extra, 2.0 * torch.eye(12), atol=1e-5)
    torch.manual_seed(99)
    assert torch.equal(build_actor_critic(cfg, privileged_dim=12)[1].module.mlp[0].weight[:, OBSERVATION_DIM:], extra)


# --- value normalisation ---------------------------------------------------------------------------

def test_value_norm_standardises_the_critics_targets_and_keeps_its_values_when_the_statistics_move():
    from quadwind_trl.rl.update import PPOUpdate
    from quadwind_trl.rl.value_norm import NormalizedValue

    cfg = PPOConfig(hidden=(16, 16), value_norm=True)
    torch.manual_seed(0)
    plain_actor, plain_value = build_actor_critic(replace(cfg, value_norm=False), privileged_dim=3)
    torch.manual_seed(0)
    actor, value = build_actor_critic(cfg, privileged_dim=3)
    # the same draws: the actor, its rollouts' random stream and the critic's weights are the plain run's
    assert all(torch.equal(a, b) for a, b in zip(actor.state_dict().values(), plain_actor.state_dict().values()))
    assert all(torch.equal(a, b) for a, b in zip(value.parameters(), plain_value.parameters()))
    head = next(m for m in value.modules() if isinstance(m, NormalizedValue))
    td = TensorDict({"observation": torch.randn(64, OBSERVATION_DIM), "privileged": torch.randn(64, 3)}, [64])
    learner = PPOUpdate(actor, value, cfg)
    targets = -35.0 + 20.0 * torch.randn(64, 1)  # return units: about the horizontal task's
    before = value(td.clone())["state_value"]
    head.update(targets)
    assert torch.allclose(head.norm.mean, targets.mean(0), rtol=1e-6)
    assert torch.allclose(head.norm.scale(), targets.std(0, unbiased=False), rtol=1e-5)
    # PopArt's output preservation: the new statistics move no prediction (GAE's values stay the critic's)
    assert torch.allclose(value(td.clone())["state_value"], before, rtol=1e-5, atol=1e-5)
    # the critic's network outputs standardised values; the critic gives them in return units
    raw = head.net(td["observation"], td["privileged"])
    assert torch.allclose(value(td.clone())["state_value"], head.norm.mean + head.norm.scale() * raw, rtol=1e-6)
    # the loss compares standardised prediction and target, and trains the critic the GAE reads
    td["value_target"], td["advantage"] = targets + 5.0, torch.randn(64, 1)
    loss = learner.loss.loss_critic(td)[0].mean()
    expected = cfg.critic_coeff * ((head.norm.normalize(td["value_target"]) - raw) ** 2).mean()
    assert torch.allclose(loss, expected, rtol=1e-5)
    out_weight = head.net.mlp[-1].weight.clone()
    learner.optim.zero_grad()
    loss.backward()
    learner.optim.step()
    assert not torch.equal(out_weight, head.net.mlp[-1].weight)
    with pytest.raises(ValueError, match=r"PPOConfig\.value_norm='yes'; allowed: True or False"):
        PPOConfig(value_norm="yes").validate()


def test_value_norm_is_recorded_checkpointed_continued_on_resume_and_another_setting_is_refused(tmp_path):
    spec = hover_spec(duration_s=1.0)
    cfg = PPOConfig(total_frames=2 * 32, num_envs=4, steps_per_env=8, epochs=1, minibatch=16, hidden=(32, 32),
                    value_norm=True, eval_every_frames=0, checkpoint_every_frames=1)
    out = tmp_path / "run"
    PPOTrainer(spec, cfg, out, progress=False).train()
    latest = torch.load(out / "checkpoints" / "latest.pt", weights_only=True)
    assert latest["ppo_config"]["value_norm"] is True
    assert float(latest["value"]["module.norm.count"]) == 2 * 32 and float(latest["value"]["module.norm.m2"]) > 0
    assert json.loads((out / "policy.json").read_text())["ppo_config"]["value_norm"] is True
    assert json.loads((out / "config.json").read_text())["ppo_config"]["value_norm"] is True
    std = (out / "logs" / "ppo" / "scalars" / "train" / "value_target_std.csv").read_text().split()
    assert len(std) == 2 and all(float(r.split(",")[1]) > 0 for r in std)
    load_policy(out / "policy.pt")  # the actor is rebuilt as any other
    with pytest.raises(ResumeMismatch, match=r"PPOConfig\.value_norm=False but the checkpoint's run used True"):
        PPOTrainer(spec, replace(cfg, value_norm=False, total_frames=3 * 32), out, progress=False).train(resume=True)
    PPOTrainer(spec, replace(cfg, total_frames=3 * 32), out, progress=False).train(resume=True)
    latest = torch.load(out / "checkpoints" / "latest.pt", weights_only=True)
    assert float(latest["value"]["module.norm.count"]) == 3 * 32  # continued, not restarted


@pytest.mark.parametrize("lever", ["value_norm", "oracle_wind"])
def test_the_value_norm_and_oracle_wind_catalogue_entries_train_a_quick_run_on_the_observer(tmp_path, lever):
    from quadwind_trl.rl.screening import LEVERS

    flags = LEVERS["horizontal"][lever]
    # the oracle reads the true mean wind and runs no estimator; the other trains on the untrained one
    estimator = () if lever == "oracle_wind" else ("--untrained-estimator",)
    args = build_parser("horizontal", "").parse_args([*flags, *estimator, "--quick", "--base-controller", "dob",
                                                      "--no-progress", "--out", str(tmp_path / "run")])
    manifest = run("horizontal", args)
    assert manifest["frames"] == 4 * 8 * 32 and manifest["env_spec"]["env_config"]["controller"]["disturbance"] == "observer"
    assert manifest["ppo_config"]["value_norm"] is (lever == "value_norm")
    assert manifest["env_spec"]["wind_input"] == ("truth" if lever == "oracle_wind" else "estimate")
    assert math.isfinite(manifest["metrics"]["rmse"])


# --- the screening recipe -------------------------------------------------------------------------

def test_lever_settings_are_catalogue_names_or_named_recipe_flags():
    from quadwind_trl.rl.screening import LEVERS, parse_lever

    assert parse_lever("memory4", "horizontal") == ("memory4", ("--memory-frames", "4"))
    assert parse_lever("mem8=--memory-frames 8", "vertical") == ("mem8", ("--memory-frames", "8"))
    assert LEVERS["horizontal"]["residual"] == ()
    assert RLEnvSpec(preview_inputs=LEVERS["vertical"]["preview"][1:]).preview_inputs == PREVIEW_CHANNELS
    with pytest.raises(ValueError, match=r"lever 'memory'; allowed: \[.*'memory4'.*\] or NAME=FLAGS"):
        parse_lever("memory", "horizontal")
    with pytest.raises(ValueError, match=r"NAME=FLAGS needs a NAME of letters, digits and _; got 'mem 8'"):
        parse_lever("mem 8=--memory-frames 8", "horizontal")


def test_screen_plan_refuses_more_validation_episodes_than_the_sweep_has_before_training():
    from quadwind_trl.rl.screening import ScreenPlan

    n = validation_scenarios("horizontal").batch_size[0]
    assert ScreenPlan(val_episodes=n).val_episodes == n
    with pytest.raises(ValueError, match=rf"ScreenPlan.val_episodes={n + 1}; allowed: 1 to {n} \(the horizontal"):
        ScreenPlan(val_episodes=n + 1)


def test_a_screen_row_names_the_commit_its_run_started_from(tmp_path, monkeypatch):
    from quadwind_trl.rl import screening

    tree = {"commit": "started-at"}

    def train(*args, **kwargs):  # someone commits while the run trains
        tree["commit"] = "committed-while-training"
        return {"frames": 8, "wall_time_s": 1.0}

    monkeypatch.setattr(screening, "git_commit", lambda: tree["commit"])
    monkeypatch.setattr(screening, "run", train)
    axis = {"gain_pct": 1.0, "ci_low_pct": 0.0, "ci_high_pct": 2.0}
    monkeypatch.setattr(screening, "score_on_validation", lambda policy, plan: {"xy": axis, "z": axis, "eval_s": 1.0})
    plan = screening.ScreenPlan(seeds=(0,), frames=8, out=tmp_path / "out", runs=tmp_path / "runs")
    (row,) = screening.screen(plan, log=lambda line: None)
    assert row.git_commit == "started-at"
    assert json.loads(plan.row_path("residual", 0).read_text())["git_commit"] == "started-at"


def test_a_screen_row_says_when_one_episode_decides_the_mean_gain():
    from quadwind_trl.rl.screening import ScreenRow, _gain, table

    base = torch.ones(5)
    policy = torch.tensor([0.9, 0.9, 0.9, 0.95, 5.0])  # four small wins, one episode lost by far
    xy = _gain(base, policy, resamples=200)
    assert math.isclose(xy["gain_pct"], 100 * (1 - 8.65 / 5), rel_tol=1e-6)  # the mean: -73 %
    assert math.isclose(xy["median_episode_gain_pct"], 10.0, rel_tol=1e-6)  # the typical episode: +10 %
    assert xy["worst_episode"] == {"index": 4, "base_m": 1.0, "policy_m": 5.0}
    row = ScreenRow(lever="x", flags=[], seed=0, regime="horizontal", base="dob", frames=1, train_wall_s=1.0, wall_s=60.0,
                    policy="p", git_commit=None, validation={"xy": xy, "z": _gain(base, base, 200),
                                                              "crashed": {"base": 0, "policy": 0}})
    assert "| +10.0 % | 4: 1.000 -> 5.000 m |" in table([row], "dob")
    # a row written before screens recorded the tail still makes a table
    old = replace(row, validation={**row.validation, "xy": {k: v for k, v in xy.items() if k not in
                                                            ("median_episode_gain_pct", "worst_episode")}})
    assert table([old], "dob").rstrip().endswith("| 1.0 min | - | - |")


def test_screens_run_beside_each_other_are_collected_into_one(tmp_path):
    """Seeds screened in folders of their own (a screen holds its folder) gather into one screen:
    every row, the summary over all seeds and every command; folders of another base, or a run
    found twice, are refused."""
    import subprocess
    import sys

    from quadwind_trl.rl.screening import ScreenRow, _gain, collect

    from test_ppo import ROOT

    def folder(name: str, seed: int, gain: float, base: str = "dob") -> Path:
        xy = _gain(torch.ones(4), torch.full((4,), 1.0 - gain), resamples=100)
        row = ScreenRow(lever="base_state", flags=["--base-state-inputs", "all"], seed=seed, regime="horizontal",
                        base=base, frames=512, train_wall_s=1.0, wall_s=60.0, policy="p", git_commit="abc1234" * 5 + "ab",
                        validation={"xy": xy, "z": _gain(torch.ones(4), torch.ones(4), 100),
                                    "crashed": {"base": 0, "policy": 0}})
        (tmp_path / name / "rows").mkdir(parents=True)
        (tmp_path / name / "rows" / f"base_state_seed{seed}.json").write_text(json.dumps(asdict(row)))
        (tmp_path / name / "screen.json").write_text(json.dumps({"command": f"python recipes/screen_levers.py --seeds {seed}"}))
        return tmp_path / name

    seed0, seed1 = folder("s0", 0, 0.10), folder("s1", 1, 0.20)
    rows, commands = collect([seed0, seed1])
    assert [r.seed for r in rows] == [0, 1] and commands == [f"python recipes/screen_levers.py --seeds {k}" for k in (0, 1)]
    with pytest.raises(ValueError, match="base_state seed 0 is in"):
        collect([seed0, seed0])
    with pytest.raises(ValueError, match="other \\(regime, base"):
        collect([seed0, folder("other", 2, 0.1, base="dob_inner")])
    out = tmp_path / "together"
    done = subprocess.run([sys.executable, str(ROOT / "recipes" / "screen_levers.py"), "--collect", str(seed0), str(seed1),
                           "--out", str(out)], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-3000:]
    assert sorted(p.name for p in (out / "rows").iterdir()) == ["base_state_seed0.json", "base_state_seed1.json"]
    from quadwind_trl.manifest import git_commit

    assert json.loads((out / "screen.json").read_text())["git_commit"] == git_commit()  # the code's, as checked out
    summary = json.loads((out / "screen.json").read_text())["summary"][0]
    assert summary["seeds"] == [0, 1] and math.isclose(summary["xy"]["mean_pct"], 15.0, rel_tol=1e-6)
    md = (out / "screen.md").read_text()
    assert "`python recipes/screen_levers.py --seeds 0`" in md and "`python recipes/screen_levers.py --seeds 1`" in md
    assert "| base_state | `--base-state-inputs all` | 2 | +15.0 % [+10.0, +20.0] |" in md and "`abc1234`" in md


def test_screen_levers_quick_writes_a_row_per_run_a_table_and_resumes_from_disk(tmp_path):
    import os
    import subprocess
    import sys

    from test_ppo import ROOT

    out, runs = tmp_path / "screen", tmp_path / "runs"

    def screen(*levers: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, str(ROOT / "recipes" / "screen_levers.py"), "--quick", "--untrained-estimator", "--levers",
             *levers, "--seeds", "0", "--frames", "512", "--val-episodes", "2", "--resamples", "200", "--out", str(out),
             "--runs", str(runs)],
            capture_output=True, text=True, timeout=900, cwd=ROOT, env=dict(os.environ, PYTHONWARNINGS="ignore"))

    first = screen("mem2=--memory-frames 2")
    assert first.returncode == 0, first.stdout[-2000:] + first.stderr[-4000:]
    row = json.loads((out / "rows" / "mem2_seed0.json").read_text())
    assert (row["lever"], row["flags"], row["seed"], row["base"], row["frames"]) == ("mem2", ["--memory-frames", "2"], 0,
                                                                                    "dob", 512)
    assert row["extra_flags"] == ["--untrained-estimator"]
    for axis in ("xy", "z"):
        v = row["validation"][axis]
        assert v["episodes"] == 2 and v["ci_low_pct"] <= v["gain_pct"] <= v["ci_high_pct"]
        assert math.isclose(v["gain_pct"], 100 * (1 - v["policy_mean_m"] / v["base_mean_m"]), rel_tol=1e-9)
    assert row["wall_s"] >= row["train_wall_s"] > 0
    policy = load_policy(ROOT / row["policy"] if not Path(row["policy"]).is_absolute() else row["policy"])[1]
    assert policy["env_spec"]["memory_frames"] == 2 and policy["env_spec"]["env_config"]["controller"]["disturbance"] == "observer"
    summary = json.loads((out / "screen.json").read_text())["summary"]
    assert [s["lever"] for s in summary] == ["mem2"] and summary[0]["xy"]["mean_pct"] == row["validation"]["xy"]["gain_pct"]
    md = (out / "screen.md").read_text()
    assert "| mem2 | `--memory-frames 2` | 1 |" in md and "| mem2 | 0 |" in md
    # a second screen finds the run finished on disk and trains nothing
    again = screen("mem2=--memory-frames 2")
    assert again.returncode == 0 and "finished earlier" in again.stdout and "training:" not in again.stdout
    # the same name for other flags is refused before anything trains
    other = screen("mem2=--memory-frames 3")
    assert other.returncode == 1 and "error: " in other.stderr and "give the setting another name" in other.stderr
    assert "training:" not in other.stdout


def test_the_gym_classes_size_their_observation_space_to_the_levers():
    import gymnasium as gym
    import numpy as np

    import quadwind_trl.gym as qgym

    from test_gym import _short

    envs = gym.make_vec(qgym.ENV_IDS["horizontal"], num_envs=2, memory_frames=3, **_short("horizontal"))
    assert envs.single_observation_space.shape == (3 * OBSERVATION_DIM,)
    obs, _ = envs.reset(seed=0)
    assert obs.shape == (2, 3 * OBSERVATION_DIM) and envs.observation_space.contains(obs)
    obs, *_ = envs.step(np.zeros((2, 4), np.float32))
    assert obs.shape == (2, 3 * OBSERVATION_DIM)
