"""The RL training / evaluation env: ``QuadWindEnv`` + the wind-aware transform stack.

    env = make_env("horizontal", bundle, num_envs=64)                     # wind-aware training
    env = make_env("horizontal", bundle, 225, wind_input="zero",           # the ablation, frozen
                   vecnorm_state=ckpt["vecnorm"], scenario_sampler=None)   # normalisation

Stack (``env.transform[i]``)::

    0 EpisodeControl      first-episode de-synchronisation / truncation on request (training)
    1 WindEstimate        wind_hat: estimate (frozen net + EMA) | truth (oracle)
    2 PolicyObservation   observation [23]
    3 RunningObsNorm      (VecNormV2) running mean/var of observation, reduce_batch_dims=True, decay=1.0
    4 ClipTransform       observation clipped to [-obs_clip, obs_clip] after normalisation
    5 WindZero            (wind_input="zero" only) observation[13:15] = 0
    . RewardSum, StepCounter   episode_reward, step_count for logging

Everything that defines an env is in :class:`RLEnvSpec` (a frozen dataclass of plain values and
configs), and :class:`EnvFactory` builds the env from it in any process (it loads the estimator
from its path there), so TorchRL's multi-process collectors can construct it.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal, TypeVar

import torch
from torchrl.envs import ClipTransform, Compose, RewardSum, StepCounter, TransformedEnv, VecNormV2

from ..config import EnvConfig
from ..data.features import make_extractor
from ..envs.quad_env import QuadWindEnv, ScenarioSampler
from ..envs.scenarios import RegimeRanges
from ..envs.trajectories import HORIZONTAL, VERTICAL
from ..modules.wind_estimator import CHECKPOINT_DIR, AttentionGRUEstimator, EstimatorBundle, EstimatorConfig
from ..regimes import HORIZONTAL_RL, VERTICAL_RL, regime_config
from ..transforms import EpisodeControl, PolicyObservation, RunningObsNorm, WindEstimate, WindZero

T = TypeVar("T")
Regime = Literal["horizontal", "vertical"]
WindInput = Literal["estimate", "zero", "truth"]
WIND_INPUTS = ("estimate", "zero", "truth")
DEFAULT_TRAJECTORIES = {"horizontal": HORIZONTAL, "vertical": VERTICAL}
DEFAULT_RANGES = {"horizontal": HORIZONTAL_RL, "vertical": VERTICAL_RL}


def _check_regime(regime: str) -> None:
    if regime not in ("horizontal", "vertical"):
        raise ValueError(f"regime={regime!r}; allowed: 'horizontal', 'vertical'")


def untrained_estimator(schema: str = "horizontal", seed: int = 0, config: EnvConfig | None = None) -> EstimatorBundle:
    """A seeded, randomly initialised estimator with identity standardisation, for development
    and smoke tests only (its outputs are meaningless)."""
    channels = make_extractor(schema, config).channels
    gen_state = torch.random.get_rng_state()
    torch.manual_seed(seed)
    model = AttentionGRUEstimator(EstimatorConfig(in_channels=len(channels)))
    torch.random.set_rng_state(gen_state)
    c = len(channels)
    return EstimatorBundle(
        model=model.eval().requires_grad_(False),
        schema=schema,
        channels=channels,
        feature_mean=torch.zeros(c),
        feature_std=torch.ones(c),
        label_mean=torch.zeros(2),
        label_std=torch.ones(2),
        manifest={"untrained": True, "seed": seed},
    )


def default_estimator_path(regime: Regime) -> Path:
    return CHECKPOINT_DIR / f"estimator_{regime}.pt"


def load_estimator(regime: Regime, path: str | Path | None = None, *, untrained: bool = False, seed: int = 0,
                   config: EnvConfig | None = None, device="cpu") -> EstimatorBundle:
    """The estimator at ``path`` (default: the shipped one for ``regime``); with ``untrained=True``
    and no path, a seeded random one. Fails with a clear message when nothing fits."""
    _check_regime(regime)
    if path is None and untrained:
        return untrained_estimator(regime, seed, config).to(device)
    path = Path(path) if path is not None else default_estimator_path(regime)
    if not path.exists():
        raise FileNotFoundError(
            f"no estimator checkpoint at {path}. Train one (recipes/train_estimator.py --regime {regime}) "
            "and pass --estimator PATH, or pass --untrained-estimator for a smoke test (random estimator: "
            "the wind channels are then meaningless)"
        )
    return EstimatorBundle.load(path, expect_channels=make_extractor(regime, config).channels, device=device)


def make_env(
    regime: Regime,
    estimator_bundle: EstimatorBundle | None,
    num_envs: int,
    wind_input: WindInput = "estimate",
    device: str | torch.device = "cpu",
    seed: int = 0,
    *,
    config: EnvConfig | None = None,
    trajectories: tuple[str, ...] | None = None,
    ranges: RegimeRanges | None = None,
    start: Literal["ground", "pattern"] = "ground",
    desync_steps: int = 0,
    obs_clip: float | None = 10.0,
    vecnorm_state: dict | None = None,
    freeze_norm: bool | None = None,
    compile_step: bool = False,
) -> TransformedEnv:
    """The transformed env of one regime (see the module docstring for the stack).

    Args:
        regime: ``"horizontal"`` (5 fixed-altitude trajectories, ``HORIZONTAL_RL``, ``w_z = 1``)
            or ``"vertical"`` (4 climbing trajectories, ``VERTICAL_RL``, ``w_z = 0.5``).
        estimator_bundle: the frozen estimator (may be None for ``wind_input="truth"``).
        wind_input: ``"estimate"`` (paper), ``"zero"`` (the ablation: same stack, the policy's wind
            inputs forced to 0) or ``"truth"`` (oracle: the true mean wind).
        config: env config; default ``regime_config(regime)``.
        trajectories, ranges, start: the training distribution (defaults: the regime's library,
            its RL ranges, episodes starting on the ground).
        desync_steps: first-episode random truncation (0: off; training uses ~ an episode length).
        vecnorm_state: a saved ``VecNormV2`` state dict (``vecnorm_state_dict(env)``) to load.
        freeze_norm: freeze the normalisation statistics (default: frozen iff ``vecnorm_state``).
    """
    _check_regime(regime)
    if wind_input not in WIND_INPUTS:
        raise ValueError(f"wind_input={wind_input!r}; allowed: {WIND_INPUTS}")
    if wind_input != "truth" and estimator_bundle is None:
        raise ValueError(f"wind_input={wind_input!r} needs an estimator bundle")
    if estimator_bundle is not None and estimator_bundle.schema != regime:
        raise ValueError(f"the estimator was trained on the {estimator_bundle.schema!r} schema, not {regime!r}")
    cfg = config if config is not None else regime_config(regime)
    sampler = ScenarioSampler(
        ranges=ranges if ranges is not None else DEFAULT_RANGES[regime],
        trajectories=tuple(trajectories) if trajectories is not None else DEFAULT_TRAJECTORIES[regime],
        start=start,
    )
    base = QuadWindEnv(cfg, batch_size=[num_envs], device=device, scenario_sampler=sampler, seed=seed, compile_step=compile_step)
    source = "truth" if wind_input == "truth" else "estimate"
    transforms = [
        EpisodeControl(desync_steps, seed=seed, align=cfg.timing.decisions_per_log),
        WindEstimate(estimator_bundle if source == "estimate" else None, source=source, config=cfg),
        PolicyObservation(cfg),
        RunningObsNorm(in_keys=["observation"], decay=1.0, eps=1e-4, reduce_batch_dims=True),
    ]
    if obs_clip is not None:
        transforms.append(ClipTransform(in_keys=["observation"], low=-obs_clip, high=obs_clip))
    if wind_input == "zero":
        transforms.append(WindZero())
    transforms += [RewardSum(in_keys=["reward"], out_keys=["episode_reward"], reset_keys=["_reset"]), StepCounter()]
    env = TransformedEnv(base, Compose(*transforms))
    if vecnorm_state is not None:
        load_vecnorm_state(env, vecnorm_state)
    if freeze_norm or (freeze_norm is None and vecnorm_state is not None):
        vecnorm(env).freeze()
    return env


def find_transform(env: TransformedEnv, cls: type[T]) -> T:
    """The first transform of type ``cls`` in ``env``'s stack."""
    for t in env.transform:
        if isinstance(t, cls):
            return t
    raise KeyError(f"no {cls.__name__} in this env's transforms")


def vecnorm(env: TransformedEnv) -> VecNormV2:
    return find_transform(env, VecNormV2)


def episode_control(env: TransformedEnv) -> EpisodeControl:
    return find_transform(env, EpisodeControl)


def wind_estimate(env: TransformedEnv) -> WindEstimate:
    return find_transform(env, WindEstimate)


def vecnorm_state_dict(env: TransformedEnv) -> dict:
    """The normalisation statistics (a plain, ``torch.load(weights_only=True)``-able dict)."""
    return dict(vecnorm(env).state_dict())


def load_vecnorm_state(env: TransformedEnv, state: dict) -> None:
    vecnorm(env).load_state_dict(state)


@dataclass(frozen=True)
class RLEnvSpec:
    """Everything :func:`make_env` needs, as plain values (picklable; the estimator by path)."""

    regime: Regime = "horizontal"
    num_envs: int = 64
    wind_input: WindInput = "estimate"
    device: str = "cpu"
    seed: int = 0
    estimator_path: str | None = None  # None: the shipped estimator (or untrained, below)
    untrained_estimator: bool = False
    config: EnvConfig | None = None
    trajectories: tuple[str, ...] | None = None
    ranges: RegimeRanges | None = None
    start: Literal["ground", "pattern"] = "ground"
    desync_steps: int = 0
    obs_clip: float | None = 10.0
    compile_step: bool = False

    @property
    def env_config(self) -> EnvConfig:
        return self.config if self.config is not None else regime_config(self.regime)


@dataclass
class EnvFactory:
    """Picklable env constructor: ``EnvFactory(spec)()`` builds ``make_env`` from ``spec``.

    ``bundle`` may be given to share an already loaded estimator in-process (it is dropped when
    the factory is pickled: other processes load it from ``spec.estimator_path``)."""

    spec: RLEnvSpec
    bundle: EstimatorBundle | None = field(default=None, repr=False)

    def __getstate__(self):
        return {"spec": self.spec, "bundle": None}

    def estimator(self) -> EstimatorBundle | None:
        s = self.spec
        if s.wind_input == "truth" and s.estimator_path is None and not s.untrained_estimator:
            return None
        if self.bundle is None:
            self.bundle = load_estimator(
                s.regime, s.estimator_path, untrained=s.untrained_estimator, config=s.env_config, device=s.device
            )
        return self.bundle

    def __call__(self, **overrides) -> TransformedEnv:
        s = replace(self.spec, **{k: v for k, v in overrides.items() if k in RLEnvSpec.__dataclass_fields__})
        extra = {k: v for k, v in overrides.items() if k not in RLEnvSpec.__dataclass_fields__}
        return make_env(
            s.regime,
            self.estimator(),
            s.num_envs,
            s.wind_input,
            s.device,
            s.seed,
            config=s.env_config,
            trajectories=s.trajectories,
            ranges=s.ranges,
            start=s.start,
            desync_steps=s.desync_steps,
            obs_clip=s.obs_clip,
            compile_step=s.compile_step,
            **extra,
        )


__all__ = [
    "EnvFactory",
    "RLEnvSpec",
    "make_env",
    "untrained_estimator",
    "load_estimator",
    "default_estimator_path",
    "find_transform",
    "vecnorm",
    "vecnorm_state_dict",
    "load_vecnorm_state",
    "episode_control",
    "wind_estimate",
]
