"""The residual wrench policy: the actor-critic networks and the policy checkpoint format.

Initialisation follows SB3: orthogonal weights, gain sqrt(2) in the hidden layers, 0.01 on the
action mean (the initial deterministic policy is ~ the PD baseline), 1 on the value output.

A policy file (``policy.pt``, or a training checkpoint, which adds the value network, optimiser,
RNG and progress) is the dict :func:`policy_payload` makes; :func:`load_policy` reads either and
rebuilds the actor the file's env spec describes (its residual's target, base-state inputs and
memory: :func:`network_dims`; files from before these settings: the paper's 23 inputs and its
residual on the wrench).
"""
from __future__ import annotations

import math
from dataclasses import asdict, fields
from pathlib import Path
from typing import Mapping, Sequence

import torch
from tensordict.nn import AddStateIndependentNormalScale, TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.envs.utils import ExplorationType
from torchrl.modules import GRUModule, ProbabilisticActor, TanhNormal, ValueOperator

from ..config import ResidualConfig, config_to_dict
from ..keys import OBSERVATION_DIM, OBSERVATION_KEY, PRIVILEGED_KEY, RECURRENT_KEY, observation_channels
from ..manifest import repo_relative
from ..validation import load_checkpoint
from .config import ACTIVATIONS, PPOConfig
from .envs import RLEnvSpec
from .value_norm import NormalizedValue

CHECKPOINT_FORMAT = 1
# what a recurrent actor's GRU hands its MLP
MEMORY_KEY = "memory"


def _mlp(sizes: Sequence[int], activation: type[nn.Module], out_gain: float) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        lin = nn.Linear(a, b)
        last = i == len(sizes) - 2
        nn.init.orthogonal_(lin.weight, gain=out_gain if last else math.sqrt(2.0))
        nn.init.zeros_(lin.bias)
        layers.append(lin)
        if not last:
            layers.append(activation())
    return nn.Sequential(*layers)


class _ConcatInputs(nn.Module):
    """An MLP over its inputs side by side (the asymmetric critic: observation and privileged)."""

    def __init__(self, mlp: nn.Sequential):
        super().__init__()
        self.mlp = mlp

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        return self.mlp(torch.cat(inputs, -1))


# the seed offset of the generator that draws an asymmetric critic's privileged-input weights
# (any fixed value: its stream must only differ from the run's, which is seeded with cfg.seed)
PRIVILEGED_INIT_OFFSET = 104_729


def _with_inputs(mlp: nn.Sequential, extra: int, seed: int) -> nn.Sequential:
    """``mlp`` reading ``extra`` more inputs after its own. Their first-layer weights are drawn
    (orthogonal, gain sqrt(2), as the layer's) from a generator of their own, seeded ``seed`` +
    :data:`PRIVILEGED_INIT_OFFSET`, and the layer is rebuilt without drawing: the global random
    stream, from which the rollouts draw their exploration, is then where the plain critic leaves
    it. With and without the privileged lever a run's actor, its first rollouts and the critic's
    weights on the observation are the same, so a screen compares the lever with the plain
    residual seed by seed, on the critic alone."""
    first = mlp[0]
    columns = torch.empty(first.out_features, extra)
    nn.init.orthogonal_(columns, gain=math.sqrt(2.0), generator=torch.Generator().manual_seed(seed + PRIVILEGED_INIT_OFFSET))
    wide = nn.utils.skip_init(nn.Linear, first.in_features + extra, first.out_features)
    with torch.no_grad():
        wide.weight.copy_(torch.cat((first.weight, columns), -1))
        wide.bias.copy_(first.bias)
    mlp[0] = wide
    return mlp


def residual_target(env_spec: RLEnvSpec | Mapping) -> str:
    """What the residual of an env spec (an :class:`RLEnvSpec` or a policy file's ``env_spec``)
    acts on, ``ResidualConfig.acts_on``: files saved before the setting acted on the wrench."""
    if isinstance(env_spec, RLEnvSpec):
        return env_spec.env_config.residual.acts_on
    return env_spec["env_config"]["residual"].get("acts_on", "wrench")


def network_dims(env_spec: RLEnvSpec | Mapping) -> dict[str, int]:
    """The networks' widths for an env spec (an :class:`RLEnvSpec` or a policy file's
    ``env_spec``; older files lack the learning levers' settings and get the paper's 23 inputs and
    4 actions): ``obs_dim`` = (23, or 22 with the residual on the acceleration, + base-state
    channels) x memory frames, ``privileged_dim`` = the critic's privileged channels,
    ``action_dim`` = the residual's channels (4 on the wrench, 3 on the acceleration);
    :func:`build_actor_critic` keywords."""
    get = (lambda name, default: getattr(env_spec, name)) if isinstance(env_spec, RLEnvSpec) else env_spec.get
    target = residual_target(env_spec)
    per_frame = len(observation_channels(target)) + len(get("base_state_inputs", ())) + len(get("preview_inputs", ()))
    return {"obs_dim": per_frame * int(get("memory_frames", 1)), "privileged_dim": len(get("privileged_inputs", ())),
            "recurrent_hidden": int(get("recurrent_hidden", 0)), "action_dim": ResidualConfig(acts_on=target).channels}


def check_recurrent(cfg: PPOConfig, spec: RLEnvSpec) -> None:
    """Refuse, naming the fields, the PPO settings a recurrent actor (``spec.recurrent_hidden``)
    cannot train with: its update takes whole rows of a batch as sequences (a minibatch of
    ``minibatch / steps_per_env`` rows, so the hidden state runs through each row's steps in order),
    and its collection runs in this process (the hidden state through collection workers or Ray
    actors is not verified)."""
    if not spec.recurrent_hidden:
        return
    if cfg.minibatch % cfg.steps_per_env:
        raise ValueError(f"RLEnvSpec.recurrent_hidden={spec.recurrent_hidden}: PPOConfig.minibatch={cfg.minibatch} must be "
                         f"a multiple of steps_per_env={cfg.steps_per_env} (a recurrent minibatch is whole rows of the "
                         "batch; --steps-per-env)")
    if cfg.collect_workers != 1 or cfg.collector != "local":
        raise ValueError(f"RLEnvSpec.recurrent_hidden={spec.recurrent_hidden}: PPOConfig.collect_workers="
                         f"{cfg.collect_workers}, collector={cfg.collector!r}; allowed with a recurrent actor: "
                         "collect_workers=1, collector='local' (the hidden state is carried in this process)")


def build_actor_critic(cfg: PPOConfig, obs_dim: int = OBSERVATION_DIM, action_dim: int = 4,
                       action_low: float = -1.0, action_high: float = 1.0, *,
                       privileged_dim: int = 0, recurrent_hidden: int = 0) -> tuple[ProbabilisticActor, ValueOperator]:
    """TanhNormal actor (``observation`` -> ``action``, ``action_log_prob``) and value critic
    (``observation``, and with ``privileged_dim`` > 0 also ``privileged``: the asymmetric critic,
    whose extra inputs the actor never reads; with ``cfg.value_norm`` its network's output is
    standardised and rescaled to returns by :class:`~quadwind_trl.rl.value_norm.NormalizedValue`).
    With ``recurrent_hidden`` > 0 the actor reads its observations through a GRU of that size
    (TorchRL's ``GRUModule``: hidden state ``recurrent_state``, restarted at 0 where ``is_init``)
    before its MLP."""
    act = ACTIVATIONS[cfg.activation]
    sizes = (obs_dim, *cfg.hidden)
    scale = AddStateIndependentNormalScale(action_dim, scale_mapping="exp", init_value=math.log(cfg.init_scale))
    if recurrent_hidden:
        memory = GRUModule(input_size=obs_dim, hidden_size=recurrent_hidden, in_keys=[OBSERVATION_KEY, RECURRENT_KEY, "is_init"],
                           out_keys=[MEMORY_KEY, ("next", RECURRENT_KEY)])
        head = TensorDictModule(nn.Sequential(_mlp((recurrent_hidden, *cfg.hidden, action_dim), act, 0.01), scale),
                                in_keys=[MEMORY_KEY], out_keys=["loc", "scale"])
        module = TensorDictSequential(memory, head)
    else:  # the paper's actor, with the parameter names of every policy file before the recurrent one
        module = TensorDictModule(nn.Sequential(_mlp((*sizes, action_dim), act, 0.01), scale), in_keys=[OBSERVATION_KEY],
                                  out_keys=["loc", "scale"])
    actor = ProbabilisticActor(
        module,
        in_keys=["loc", "scale"],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": action_low, "high": action_high},
        return_log_prob=True,
        default_interaction_type=ExplorationType.DETERMINISTIC,
    )
    critic, in_keys = _mlp((*sizes, 1), act, 1.0), [OBSERVATION_KEY]  # the paper's critic
    if privileged_dim:  # the same network, reading the privileged channels after the observation
        critic, in_keys = _ConcatInputs(_with_inputs(critic, privileged_dim, cfg.seed)), [OBSERVATION_KEY, PRIVILEGED_KEY]
    return actor, ValueOperator(NormalizedValue(critic) if cfg.value_norm else critic, in_keys=in_keys)


def action_scale(actor: ProbabilisticActor) -> float:
    """Mean standard deviation of the pre-tanh Normal (the state-independent exploration scale)."""
    scale = next(m for m in actor.modules() if isinstance(m, AddStateIndependentNormalScale))
    return float(scale.state_independent_scale.detach().exp().mean())


def spec_to_dict(spec: RLEnvSpec) -> dict:
    """``spec`` as JSON-ready values (configs as nested dicts, plus the resolved ``env_config``;
    the estimator's path relative to the repository, as every manifest records paths)."""
    d = {}
    for f in fields(spec):
        v = getattr(spec, f.name)
        d[f.name] = config_to_dict(v) if f.name in ("config", "ranges") and v is not None else v
    if d.get("estimator_path") is not None:
        d["estimator_path"] = repo_relative(d["estimator_path"])
    d["env_config"] = config_to_dict(spec.env_config)
    return d


def policy_payload(actor: ProbabilisticActor, vecnorm_state: dict, cfg: PPOConfig, spec: RLEnvSpec) -> dict:
    """What a policy file holds: the actor's weights, the normalisation to freeze at evaluation,
    and the PPO config and env spec that rebuild both."""
    return {
        "format": CHECKPOINT_FORMAT,
        "kind": "policy",  # validation.load_checkpoint tells a policy from an estimator by it
        "policy": actor.state_dict(),
        "vecnorm": vecnorm_state,
        "ppo_config": asdict(cfg),
        "env_spec": spec_to_dict(spec),
        "observation_channels": list(spec.observation_channels),  # one frame's
    }


def load_policy(path: str | Path, device="cpu") -> tuple[ProbabilisticActor, dict]:
    """A saved policy (``policy.pt`` or a training checkpoint): ``(actor, payload)``.

    ``payload["vecnorm"]`` is the frozen normalisation to pass to ``make_env(...,
    vecnorm_state=...)``; ``payload["ppo_config"]`` / ``payload["env_spec"]`` describe the run."""
    payload = load_checkpoint(path, "policy", device)
    saved = payload.get("observation_channels")
    layout = observation_channels(residual_target(payload["env_spec"]))
    expected = (list(layout) + list(payload["env_spec"].get("base_state_inputs", ()))
                + list(payload["env_spec"].get("preview_inputs", ())))
    if saved is not None and list(saved) != expected:
        raise ValueError(f"{path} was trained on another observation layout ({len(saved)} channels: {saved}); "
                         f"this version's is keys.observation_channels ({len(layout)} channels for its residual) "
                         f"followed by the policy's base_state_inputs and preview_inputs: {expected}")
    cfg = payload["ppo_config"]
    cfg = PPOConfig(**{**cfg, "hidden": tuple(cfg["hidden"])})
    # the actor reads no privileged input: the file's critic, if any, is not rebuilt here
    dims = network_dims(payload["env_spec"])
    actor, _ = build_actor_critic(cfg, dims["obs_dim"], dims["action_dim"], recurrent_hidden=dims["recurrent_hidden"])
    actor.load_state_dict(payload["policy"])
    return actor.to(device).eval(), payload
