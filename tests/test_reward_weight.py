"""The PPO recipes' ``--reward-w-z``: the reward's height weight set from the command line, recorded
in the policy's env config, refused out of range by name, and guarded on resume (a run resumed
under another env config would mix two objectives in one policy)."""
from __future__ import annotations

import re
from dataclasses import replace

import pytest

from quadwind_trl.envs.task import TrackingTask
from quadwind_trl.regimes import REWARD_W_Z, regime_config
from quadwind_trl.rl.cli import build_parser, with_reward_w_z
from quadwind_trl.rl.envs import RLEnvSpec
from quadwind_trl.rl.policy import spec_to_dict
from quadwind_trl.rl.trainer import ResumeMismatch, check_same_env


@pytest.mark.parametrize("regime", ["horizontal", "vertical"])
def test_the_regime_preset_stays_unless_the_weight_is_given(regime):
    args = build_parser(regime, "").parse_args([])
    config = regime_config(regime)
    assert args.reward_w_z is None and with_reward_w_z(config, args.reward_w_z) is config
    assert config.reward.w_z == REWARD_W_Z[regime]
    given = build_parser(regime, "").parse_args(["--reward-w-z", "0.25"])  # neither regime's preset
    changed = with_reward_w_z(config, given.reward_w_z)
    assert changed.reward.w_z == 0.25 and replace(changed, reward=config.reward) == config  # nothing else moves
    assert TrackingTask(changed).reward.w_z == 0.25  # the task the env asks for its reward reads it


@pytest.mark.parametrize("text, message", [("-0.5", r"--reward-w-z=-0.5: allowed range: finite, >= 0"),
                                           ("inf", r"--reward-w-z=inf: allowed range: finite, >= 0"),
                                           ("beta", r"--reward-w-z='beta': expected a number >= 0")])
def test_a_bad_weight_is_refused_naming_the_option_and_range(text, message, capsys):
    with pytest.raises(SystemExit):
        build_parser("vertical", "").parse_args(["--reward-w-z", text])
    assert re.search(message, capsys.readouterr().err)


def test_the_weight_is_recorded_and_a_resume_under_another_is_refused():
    spec = RLEnvSpec(regime="vertical", untrained_estimator=True, config=with_reward_w_z(regime_config("vertical"), 0.5))
    saved = spec_to_dict(spec)
    assert saved["env_config"]["reward"]["w_z"] == 0.5
    check_same_env(saved, spec, None)  # the same run resumes
    with pytest.raises(ResumeMismatch, match=r"env config differs from the checkpoint's run in reward \(e\.g\. "
                                             r"--sensing, --reward-w-z\)"):
        check_same_env(saved, replace(spec, config=regime_config("vertical")), None)

