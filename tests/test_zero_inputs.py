"""Policies trained and flown without some inputs (``RLEnvSpec.zero_inputs``): exactly those
channels are 0 and every other one is bit-identical; the setting is validated, recorded, read back
for every flight of the policy and guarded on resume; the ablation's separately trained policies
(``trained_blind``, ``trained_oracle``) are checked before they fly."""
from __future__ import annotations

import copy
from dataclasses import replace

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import ClipTransform, RewardSum, StepCounter

from quadwind_trl.estimator import load_estimator, untrained_estimator
from quadwind_trl.evaluation.ablation import fly_controllers, summarize_ablation
from quadwind_trl.evaluation.statistics import paired_summary
from quadwind_trl.evaluation.tracking import sweep_setup
from quadwind_trl.keys import INPUT_GROUPS, OBSERVATION_CHANNELS, WIND_CHANNELS, input_channels, observation_index
from quadwind_trl.manifest import CHECKPOINT_DIR
from quadwind_trl.quick import SWEEP_QUICK
from quadwind_trl.regimes import SWEEPS
from quadwind_trl.rl.envs import RLEnvSpec, make_env, policy_env_settings
from quadwind_trl.rl.policy import spec_to_dict
from quadwind_trl.rl.trainer import ResumeMismatch, check_same_env
from quadwind_trl.transforms import EpisodeControl, PolicyObservation, RunningObsNorm, WindEstimate, ZeroInputs
from quadwind_trl.validation import load_checkpoint

from test_transforms import scenarios, short_config

AWARE = CHECKPOINT_DIR / "policy_horizontal.pt"
NO_TILT = ("roll", "pitch", "pd_thrust_over_weight")


@pytest.fixture(scope="module")
def bundle():
    return untrained_estimator("horizontal", seed=0, config=short_config())


def _observations(bundle, steps: int = 12, **settings) -> torch.Tensor:
    """``[4, steps + 1, 23]``: the observation of the same 4 episodes under zero actions."""
    env = make_env("horizontal", bundle, 4, config=short_config(), compile_step=False, **settings)
    td = env.reset(scenario=scenarios(4))
    rows = [td["observation"]]
    for _ in range(steps):
        td["action"] = torch.zeros(4, 4)
        td = env.step(td)["next"]
        rows.append(td["observation"])
    return torch.stack(rows, 1)


def _zeroed(obs: torch.Tensor, channels) -> torch.Tensor:
    return obs.index_fill(-1, torch.tensor([observation_index(c) for c in channels]), 0.0)


def test_zero_inputs_zero_exactly_those_channels_and_leave_the_rest_bit_identical(bundle):
    full = _observations(bundle)
    assert _zeroed(full, NO_TILT).ne(full).any()  # the channels carry something to remove
    # the stack without zero_inputs is the one before the setting, transform for transform
    stack = [EpisodeControl, WindEstimate, PolicyObservation, RunningObsNorm, ClipTransform, RewardSum, StepCounter]
    plain = make_env("horizontal", bundle, 1, config=short_config(), compile_step=False)
    assert [type(t) for t in plain.transform] == stack
    assert not any(isinstance(t, ZeroInputs) for t in plain.transform)
    assert torch.equal(_observations(bundle, zero_inputs=NO_TILT), _zeroed(full, NO_TILT))
    # wind_input="zero" alone: the wind channels, as an explicit zeroing of the wind-aware input
    blind = make_env("horizontal", bundle, 1, wind_input="zero", config=short_config(), compile_step=False)
    assert [type(t) for t in blind.transform] == stack[:5] + [ZeroInputs] + stack[5:]
    assert blind.transform[5].channels == WIND_CHANNELS
    assert torch.equal(_observations(bundle, wind_input="zero"), _zeroed(full, WIND_CHANNELS))
    # both: one transform zeroing the union, in observation order, whatever order they were named in
    both = make_env("horizontal", bundle, 1, wind_input="zero", zero_inputs=NO_TILT[::-1], config=short_config(),
                    compile_step=False)
    zeroed = [t for t in both.transform if isinstance(t, ZeroInputs)]
    assert len(zeroed) == 1 and zeroed[0].channels == ("roll", "pitch", "wind_fwd", "wind_left", "pd_thrust_over_weight")


def test_bad_zero_inputs_are_refused_naming_the_field_value_and_allowed_channels():
    for bad, why in ((("tilt",), "unknown channels ['tilt']"), (("roll", "roll"), "['roll'] given twice"),
                     (("wind_fwd",), "['wind_fwd'] are the wind channels, which wind_input='zero' removes"),
                     ("roll", "allowed: a tuple of channel names")):
        with pytest.raises(ValueError) as err:
            RLEnvSpec(zero_inputs=bad)
        message = str(err.value)
        assert message.startswith(f"RLEnvSpec.zero_inputs={bad!r}") and why in message, message
        allowed = message.split("allowed: ")[1]
        assert "'acc_bx'" in allowed and "'wind_fwd'" not in allowed, message
    assert RLEnvSpec(zero_inputs=["pitch", "roll"]).zero_inputs == ("pitch", "roll")  # a JSON list: the order kept
    with pytest.raises(ValueError, match=r"ZeroInputs\(channels=\('roll',\), in_key='wind_hat'\)"):
        ZeroInputs(("roll",), in_key="wind_hat")


def test_groups_expand_to_channels_in_observation_order():
    assert input_channels(["pd_thrust", "attitude", "acc_bz", "accel"]) == (
        "acc_bx", "acc_by", "acc_bz", "roll", "pitch", "pd_thrust_over_weight")  # fmt: skip
    assert all(c in OBSERVATION_CHANNELS and c not in WIND_CHANNELS for group in INPUT_GROUPS.values() for c in group)
    with pytest.raises(ValueError, match=r"zero_inputs: unknown \['tilt'\]; allowed: the groups \['accel', 'attitude', "
                                         r"'pd_thrust'\] or the channels \('alt', "):
        input_channels(["attitude", "tilt"])


def test_the_ppo_recipes_refuse_an_unknown_group_before_any_output(tmp_path, capsys):
    from quadwind_trl.rl.cli import build_parser, run

    args = build_parser("horizontal", "").parse_args(["--quick", "--zero-inputs", "attitude", "wind",
                                                      "--out", str(tmp_path / "run")])
    assert args.zero_inputs == ["attitude", "wind"]
    with pytest.raises(SystemExit, match=r"error: zero_inputs: unknown \['wind'\]"):
        run("horizontal", args)
    assert not (tmp_path / "run").exists()


def test_policies_record_zero_inputs_and_older_ones_have_none(bundle):
    recorded = spec_to_dict(RLEnvSpec(zero_inputs=NO_TILT, ema_tau_s=2.0, estimate_every_s=0.5, base_wind_input="zero"))
    assert policy_env_settings(recorded, bundle) == {"ema_tau_s": 2.0, "estimate_every_s": 0.5, "zero_inputs": NO_TILT,
                                                     "base_wind_input": "zero", "base_state_inputs": (),
                                                     "preview_inputs": (), "memory_frames": 1, "recurrent_hidden": 0}
    older = {key: value for key, value in recorded.items() if key != "zero_inputs"}
    assert policy_env_settings(older, bundle)["zero_inputs"] == ()
    spec = load_checkpoint(AWARE, "policy")["env_spec"]  # the shipped policies predate the setting
    assert "zero_inputs" not in spec and policy_env_settings(spec, None)["zero_inputs"] == ()
    # nor do they record what a feed-forward base flies on (they fly the paper's PD, which reads none)
    assert "base_wind_input" not in spec and policy_env_settings(spec, None)["base_wind_input"] == "estimate"


def test_a_resume_with_other_inputs_is_refused():
    spec = RLEnvSpec(untrained_estimator=True, zero_inputs=("roll", "pitch"))
    saved = spec_to_dict(spec)
    check_same_env(saved, replace(spec, zero_inputs=("pitch", "roll")), None)  # the same inputs
    with pytest.raises(ResumeMismatch, match=r"RLEnvSpec\.zero_inputs=\(\) but the checkpoint's run used \('roll', "
                                             r"'pitch'\); resume with the run's settings \(--zero-inputs\)"):
        check_same_env(saved, replace(spec, zero_inputs=()), None)
    with pytest.raises(ResumeMismatch, match=r"RLEnvSpec\.wind_input='zero' but .* used 'estimate'"):
        check_same_env(saved, replace(spec, wind_input="zero"), None)
    older = {key: value for key, value in spec_to_dict(replace(spec, zero_inputs=())).items() if key != "zero_inputs"}
    check_same_env(older, replace(spec, zero_inputs=()), None)


def _saved_as(tmp_path, name: str, **env_spec) -> str:
    """The shipped horizontal policy, its env spec changed by ``env_spec``."""
    payload = copy.deepcopy(load_checkpoint(AWARE, "policy"))
    payload["env_spec"].update(env_spec)
    path = tmp_path / name
    torch.save(payload, path)
    return str(path)


def test_a_policy_flies_with_its_zero_inputs_and_blind_adds_the_wind(tmp_path):
    scenarios_, _ = sweep_setup(SWEEPS["horizontal"], quick=True)
    path = _saved_as(tmp_path, "no_attitude.pt", zero_inputs=["roll", "pitch"])  # as torch.load gives it back
    flown = fly_controllers("horizontal", scenarios_[:1], path, load_estimator("horizontal"), ("aware", "blind"),
                            config_override=replace(SWEEP_QUICK, pattern_s=1.0).config, compile_step=False,
                            log_keys=("observation",))
    for name, zeroed in (("aware", ("roll", "pitch")), ("blind", ("roll", "pitch") + WIND_CHANNELS)):
        obs = flown[name].log["observation"][flown[name].log["valid"]]
        index = [observation_index(c) for c in zeroed]
        assert obs[:, index].eq(0).all(), name
        others = [i for i in range(len(OBSERVATION_CHANNELS)) if i not in index]
        assert obs[:, others].ne(0).any(0).all(), name  # the rest carry their values


def test_trained_oracle_is_refused_unless_it_trained_on_the_truth_without_the_same_inputs(tmp_path):
    scenarios_, override = sweep_setup(SWEEPS["horizontal"], quick=True)

    def fly(**trained):
        fly_controllers("horizontal", scenarios_[:1], AWARE, None, ("pd", "trained_oracle"), config_override=override,
                        trained_policies=trained)

    with pytest.raises(ValueError, match=r"controller 'trained_oracle' needs trained_policies\['trained_oracle'\]: "
                                         r"a policy trained with --wind-input truth"):
        fly()
    with pytest.raises(ValueError, match=r"trained_policies\['trained_oracle'\]=.*policy_horizontal\.pt trained with "
                                         r"wind_input='estimate'; a trained_oracle policy trains with 'truth'"):
        fly(trained_oracle=AWARE)
    with pytest.raises(ValueError, match=r"trained_policies\['trained_oracle'\]=.*trained with zero_inputs=\('roll',\), "
                                         r".* with \(\): the comparison would change more than the wind input"):
        fly(trained_oracle=_saved_as(tmp_path, "oracle_no_roll.pt", wind_input="truth", zero_inputs=("roll",)))
    with pytest.raises(ValueError, match=r"trained_policies: unknown controllers \['oracle'\]; allowed: "
                                         r"\['trained_blind', 'trained_oracle'\]"):
        fly(oracle=AWARE)


def test_trained_oracle_flies_the_oracle_worlds(tmp_path):
    # the shipped policy relabelled as trained on the truth: flown as trained_oracle it must reproduce
    # the oracle flights (the same weights, fed the true wind) to the bit, so both flew the same worlds
    scenarios_, _ = sweep_setup(SWEEPS["horizontal"], quick=True)
    flown = fly_controllers("horizontal", scenarios_[:2], AWARE, None, ("oracle", "trained_oracle"),
                            config_override=replace(SWEEP_QUICK, pattern_s=1.0).config, compile_step=False,
                            trained_policies={"trained_oracle": _saved_as(tmp_path, "oracle.pt", wind_input="truth")})
    for metric in ("rmse_xy", "rmse_z", "crashed"):
        assert torch.equal(getattr(flown["trained_oracle"], metric), getattr(flown["oracle"], metric))


def test_trained_oracle_is_summarised_against_trained_blind():
    names = ["pd", "blind", "aware", "trained_blind", "trained_oracle"]
    n, g = 8, torch.Generator().manual_seed(0)
    wind = torch.tensor([4.0] * 4 + [8.0] * 4)
    table = TensorDict({"traj_id": torch.zeros(n, dtype=torch.long), "wind_speed_ref_m_s": wind,
                        "turb_intensity": torch.full((n,), 0.1), "case_id": torch.arange(n)}, batch_size=[n])
    for name in names:
        for metric in ("rmse_xy", "rmse_z", "rmse"):
            table[f"{name}_{metric}"] = 0.5 + torch.rand(n, generator=g)
        table[f"{name}_crashed"] = torch.zeros(n, dtype=torch.bool)
    block = summarize_ablation("horizontal", table, names)["rmse_xy"]
    blind, oracle = table["trained_blind_rmse_xy"], table["trained_oracle_rmse_xy"]
    assert block["trained_oracle_vs_trained_blind"] == paired_summary(blind, oracle)
    for key, row in block["by_wind"].items():
        m = wind == float(key)
        assert row["trained_oracle"] == pytest.approx(oracle[m].double().mean().item())
        assert row["trained_oracle_perception"] == pytest.approx(
            100.0 * (1.0 - oracle[m].double().mean().item() / blind[m].double().mean().item()))
    # without a trained-blind policy there is nothing to compare the oracle-trained one with
    without = table.exclude(*(key for key in table.keys() if key.startswith("trained_blind_")))
    alone = summarize_ablation("horizontal", without, [c for c in names if c != "trained_blind"])["rmse_xy"]
    assert "trained_oracle_vs_trained_blind" not in alone and "trained_oracle_perception" not in alone["by_wind"]["4"]
