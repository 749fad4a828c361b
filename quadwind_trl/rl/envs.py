"""The RL training / evaluation env: ``QuadWindEnv`` + the wind-aware transform stack.

    env = make_env("horizontal", bundle, num_envs=64)                     # wind-aware training
    env = make_env("horizontal", bundle, 225, wind_input="zero",           # the ablation, frozen
                   vecnorm_state=ckpt["vecnorm"], scenario_sampler=None)   # normalisation

Stack (``env.transform[i]``)::

    0 EpisodeControl      first-episode de-synchronisation / truncation on request (training)
    1 WindEstimate        wind_hat: estimate (frozen net + EMA) | truth (oracle)
    . BaseWindInput       (a wind feed-forward base controller only) base_wind_ne, the base law's
                          step input: the estimate, the true mean wind or zero (base_wind_input)
    . ReferenceAhead      (preview_inputs only) ref_ahead [3, 3]: the reference 0.5, 1, 2 s ahead
    2 PolicyObservation   observation [23 + B + P]: the paper's 23, then the B base_state_inputs
                          channels, then the P preview_inputs channels
    . PrivilegedObservation  (privileged_inputs only: training) privileged [P], the critic's truth
    3 RunningObsNorm      (VecNormV2) running mean/var of observation, reduce_batch_dims=True, decay=1.0
    4 ClipTransform       observation clipped to [-obs_clip, obs_clip] after normalisation
    5 ZeroInputs          (wind_input="zero" or zero_inputs only) those channels = 0: the wind's
                          (wind_fwd, wind_left) for "zero", and the zero_inputs channels
    . ObservationStack    (memory_frames > 1 only) observation [K (23 + B)]: the last K, newest last
    . InitTracker, TensorDictPrimer   (recurrent_hidden > 0 only) is_init, recurrent_state [1, H]
    . RunningObsNorm, ClipTransform   (privileged_inputs only) the same for privileged
    . RewardSum, StepCounter   episode_reward, step_count for logging

Everything that defines an env is in :class:`RLEnvSpec` (a frozen dataclass of plain values and
configs, the one list of env settings and their defaults): :func:`build_env` builds the env of a
spec, :func:`make_env` is the keyword shorthand (its keywords are the spec's fields), and
:class:`EnvFactory` holds a spec and builds the env in any process (it loads the estimator from
its path there), so TorchRL's multi-process collectors can construct it.

The wind estimate's post-filter time constant is ``RLEnvSpec.ema_tau_s`` (default
``estimator.ema.DEFAULT_TAU_S``, the paper's); the PPO recipes train with the one chosen on the
estimator's validation flights (:func:`validated_tau_s`). How often the estimator runs is
``RLEnvSpec.estimate_every_s`` (default: every 10 Hz log tick, 0.1 s); the filter's time constant
stays in seconds whatever it is. ``RLEnvSpec.zero_inputs`` names policy inputs forced to 0 in
training and in every flight (a policy trained without them). The learning levers are off by
default: ``base_state_inputs`` (the base controller's state as policy inputs), ``preview_inputs``
(the reference ahead of now as policy inputs), ``memory_frames`` (the last K observations) and
``privileged_inputs`` (simulator truth for the critic alone, in the training env alone).

Trained policies record these settings in their env spec, and flying them must use them:
:func:`policy_env_settings` reads them (with what policies saved before a setting existed used:
their estimator checkpoint's tau, the estimator at every tick, no zeroed inputs, no base state, no
preview, no memory).
"""
from __future__ import annotations

import math

from dataclasses import dataclass, field, replace
from functools import partial
from typing import Literal, Mapping, TypeVar

import torch
from torchrl.data import Unbounded
from torchrl.envs import (ClipTransform, Compose, InitTracker, ParallelEnv, TensorDictPrimer, RemoveEmptySpecs, RewardSum, SelectTransform, StepCounter, Transform, TransformedEnv,
                          VecNormV2)

from ..config import EnvConfig
from ..envs.controller import BaseController
from ..envs.parallel import QuietParallelEnv
from ..envs.quad_env import QuadWindEnv, ScenarioSampler
from ..envs.ray_rows import RayRowsEnv
from ..envs.scenarios import RegimeRanges
from ..envs.trajectories import HORIZONTAL, VERTICAL
from ..estimator import DEFAULT_TAU_S, EMAConfig, WindEstimator, load_estimator
from ..keys import (BASE_STATE_GROUPS, OBSERVATION_KEY, PREVIEW_GROUPS, PRIVILEGED_CHANNELS, PRIVILEGED_GROUPS,
                    PRIVILEGED_KEY, RECURRENT_KEY, WIND_CHANNELS, ZEROABLE_CHANNELS, named_channels, observation_channels)
from ..regimes import HORIZONTAL_RL, VERTICAL_RL, regime_config
from ..transforms import (BaseWindInput, EpisodeControl, ObservationStack, PolicyObservation, PrivilegedObservation,
                          ReferenceAhead, RunningObsNorm, WindEstimate, ZeroInputs)
from ..transforms.observation import base_state_channels
from ..transforms.wind import estimate_stride

T = TypeVar("T")
Regime = Literal["horizontal", "vertical"]
WindInput = Literal["estimate", "zero", "truth"]
WIND_INPUTS = ("estimate", "zero", "truth")
WorkersOn = Literal["local", "ray"]
WORKERS_ON = ("local", "ray")  # where build_env's collection workers run
DEFAULT_TRAJECTORIES = {"horizontal": HORIZONTAL, "vertical": VERTICAL}
DEFAULT_RANGES = {"horizontal": HORIZONTAL_RL, "vertical": VERTICAL_RL}
# RLEnvSpec.base_state_inputs: every channel of the selected base law's state
BASE_STATE_ALL = "all"
# s: the estimator at every 10 Hz log tick (what every policy trained before the setting existed saw)
DEFAULT_ESTIMATE_EVERY_S = 0.1


def check_regime(regime: str) -> None:
    """A ``ValueError`` naming the two regimes unless ``regime`` is one of them."""
    if regime not in ("horizontal", "vertical"):
        raise ValueError(f"regime={regime!r}; allowed: 'horizontal', 'vertical'")


@dataclass(frozen=True)
class RLEnvSpec:
    """Everything that defines an RL env, as plain values (picklable; the estimator by path)."""

    regime: Regime = "horizontal"  # "horizontal" (HORIZONTAL_RL) or "vertical" (VERTICAL_RL); w_z: regimes.REWARD_W_Z
    num_envs: int = 64
    # "estimate" (paper), "zero" (the ablation: the policy's wind inputs forced to 0) or "truth" (oracle)
    wind_input: WindInput = "estimate"
    device: str = "cpu"
    seed: int = 0
    estimator_path: str | None = None  # None: the shipped estimator (or untrained, below)
    untrained_estimator: bool = False
    config: EnvConfig | None = None  # None: regime_config(regime)
    trajectories: tuple[str, ...] | None = None  # None: the regime's library
    ranges: RegimeRanges | None = None  # None: the regime's RL ranges
    start: Literal["ground", "pattern"] = "ground"
    desync_steps: int = 0  # first-episode random truncation (0: off; training uses ~ an episode length)
    obs_clip: float | None = 10.0  # observation clip after normalisation (None: off)
    # the simulator's control step through torch.compile (the RL stack's default: 3-5x the eager
    # throughput at training batch sizes, for minutes of compilation once for every batch size,
    # kept on disk for later processes); False flies it eagerly. The two agree to float rounding,
    # not bit for bit, so a replay uses the setting the run recorded.
    compile_step: bool = True
    ema_tau_s: float = DEFAULT_TAU_S  # s, the wind estimate's EMA time constant (0: raw estimate)
    # s between a row's estimator queries (a whole multiple of the log interval; the estimate is
    # held in between): a slow EMA barely moves in 0.1 s, and the estimator is most of collection
    estimate_every_s: float = DEFAULT_ESTIMATE_EVERY_S
    # policy inputs (keys.OBSERVATION_CHANNELS names) forced to exactly 0 after normalisation and
    # clipping, in training and in every flight of the policy: a policy trained without them. The
    # wind channels are not among them: wind_input="zero" removes those
    zero_inputs: tuple[str, ...] = ()
    # what a wind feed-forward base controller (ControllerConfig.disturbance="wind_model") flies
    # on: "estimate" (the estimator's filtered output, wind_hat), "truth" (the true mean wind: the
    # oracle) or "zero" (its blind twin); unused by every other base controller
    base_wind_input: WindInput = "estimate"
    # the base controller's state the policy reads after the 23 channels (keys.BASE_STATE_CHANNELS
    # names or groups the selected base law has: its force estimate, integral, feed-forward, ...; "all":
    # every one it has); () the paper's inputs
    base_state_inputs: tuple[str, ...] = ()
    # the reference ahead the policy reads after those (keys.PREVIEW_CHANNELS names or groups: where the
    # reference will be 0.5, 1 and 2 s from now, from the vehicle); () the paper's inputs
    preview_inputs: tuple[str, ...] = ()
    # simulator truth an asymmetric critic reads at training time (keys.PRIVILEGED_CHANNELS: true mean
    # wind, turbulence, true errors), never the actor; only the training env computes it
    privileged_inputs: tuple[str, ...] = ()
    # the policy reads its last memory_frames observations (env steps) side by side; 1: memoryless
    memory_frames: int = 1
    # a recurrent actor's hidden size (a GRU over the observations; 0: none): the env then carries
    # its hidden state between decisions and marks episode starts (is_init), where it restarts at 0
    recurrent_hidden: int = 0

    def __post_init__(self):
        check_regime(self.regime)
        if self.wind_input not in WIND_INPUTS:
            raise ValueError(f"RLEnvSpec.wind_input={self.wind_input!r}; allowed: {WIND_INPUTS}")
        if self.num_envs < 1:
            raise ValueError(f"RLEnvSpec.num_envs={self.num_envs}; allowed: >= 1")
        if not self.ema_tau_s >= 0:
            raise ValueError(f"RLEnvSpec.ema_tau_s={self.ema_tau_s!r} s; allowed: >= 0 (0: unfiltered)")
        estimate_stride(self.estimate_every_s, self.env_config.timing.log_dt_s, "RLEnvSpec.estimate_every_s")
        if self.base_wind_input not in WIND_INPUTS:
            raise ValueError(f"RLEnvSpec.base_wind_input={self.base_wind_input!r}; allowed: {WIND_INPUTS}")
        if self.env_config.controller.needs_wind and self.base_wind_input == "estimate" and self.wind_input == "truth":
            raise ValueError("RLEnvSpec.base_wind_input='estimate' with wind_input='truth': the env runs no estimator "
                             "then (the policy reads the true wind); give the base law the truth too, or the policy "
                             "the estimate")
        if self.desync_steps < 0:
            raise ValueError(f"RLEnvSpec.desync_steps={self.desync_steps}; allowed: >= 0")
        self._check_zero_inputs()
        self._check_levers()

    def _check_levers(self) -> None:
        """The base-state, privileged and memory settings: names the field, the value and the allowed ones."""
        base = self.base_state_inputs
        if not isinstance(base, str) and any(name in PRIVILEGED_CHANNELS or name in PRIVILEGED_GROUPS for name in base):
            raise ValueError(f"RLEnvSpec.base_state_inputs={tuple(base)!r}: "
                             f"{[n for n in base if n in PRIVILEGED_CHANNELS or n in PRIVILEGED_GROUPS]} are privileged "
                             "(simulator truth): the actor never reads them; allowed for the critic only, in "
                             "privileged_inputs (--privileged-inputs)")
        have = base_state_channels(self.env_config) if base else ()
        if not isinstance(base, str) and BASE_STATE_ALL in base:  # every channel the selected base law has
            if not have:
                raise ValueError(f"RLEnvSpec.base_state_inputs={tuple(base)!r}: this base controller keeps no state "
                                 "(the paper's PD, the wind feed-forward law); allowed: a base with integral action or "
                                 "a force estimate (--base-controller pid, dob, l1, ...)")
            base = tuple(n for n in base if n != BASE_STATE_ALL) + have
        # stored as the tuple of channels, in catalogue order (a JSON list, or a group name, is the same setting)
        object.__setattr__(self, "base_state_inputs",
                           named_channels(base, BASE_STATE_GROUPS, "RLEnvSpec.base_state_inputs", allowed=have))
        object.__setattr__(self, "preview_inputs",
                           named_channels(self.preview_inputs, PREVIEW_GROUPS, "RLEnvSpec.preview_inputs"))
        object.__setattr__(self, "privileged_inputs",
                           named_channels(self.privileged_inputs, PRIVILEGED_GROUPS, "RLEnvSpec.privileged_inputs"))
        frames = self.memory_frames
        if not isinstance(frames, int) or isinstance(frames, bool) or frames < 1:
            raise ValueError(f"RLEnvSpec.memory_frames={frames!r}; allowed: a whole number >= 1 (1: memoryless)")
        hidden = self.recurrent_hidden
        if not isinstance(hidden, int) or isinstance(hidden, bool) or hidden < 0:
            raise ValueError(f"RLEnvSpec.recurrent_hidden={hidden!r}; allowed: a whole number >= 0 (0: no recurrent actor)")

    @property
    def observation_channels(self) -> tuple[str, ...]:
        """The channels of one frame of the policy's observation: the paper's 23 (22 with the residual
        on the acceleration: :func:`~quadwind_trl.keys.observation_channels`), then ``base_state_inputs``,
        then ``preview_inputs``."""
        return self.policy_channels + self.base_state_inputs + self.preview_inputs

    @property
    def policy_channels(self) -> tuple[str, ...]:
        """The observation's channels before the base state's, for the residual this env's config has."""
        return observation_channels(self.env_config.residual.acts_on)

    def _check_zero_inputs(self) -> None:
        value = self.zero_inputs
        if not isinstance(value, (tuple, list)) or not all(isinstance(name, str) for name in value):
            raise ValueError(f"RLEnvSpec.zero_inputs={value!r}; allowed: a tuple of channel names of {ZEROABLE_CHANNELS}")
        # a list (a JSON round trip) is the same setting: stored as the tuple the field declares
        object.__setattr__(self, "zero_inputs", tuple(value))
        wind = [name for name in value if name in WIND_CHANNELS]
        if wind:
            raise ValueError(f"RLEnvSpec.zero_inputs={value!r}: {wind} are the wind channels, which wind_input='zero' "
                             f"removes (the one way the ablation recognises a policy trained without them); "
                             f"allowed: channels of {ZEROABLE_CHANNELS}")
        unknown = [name for name in value if name not in self.policy_channels]
        if unknown:
            allowed = tuple(c for c in self.policy_channels if c not in WIND_CHANNELS)
            raise ValueError(f"RLEnvSpec.zero_inputs={value!r}: unknown channels {unknown}; allowed: channels of "
                             f"{allowed}")
        if len(set(value)) < len(value):
            twice = sorted({name for name in value if value.count(name) > 1})
            raise ValueError(f"RLEnvSpec.zero_inputs={value!r}: {twice} given twice; allowed: each channel once, of "
                             f"{ZEROABLE_CHANNELS}")

    @property
    def zeroed_channels(self) -> tuple[str, ...]:
        """Every channel the env forces to 0, in observation order: ``zero_inputs``, and the wind's
        for ``wind_input="zero"``."""
        zeroed = set(self.zero_inputs) | (set(WIND_CHANNELS) if self.wind_input == "zero" else set())
        return tuple(name for name in self.policy_channels if name in zeroed)

    @property
    def env_config(self) -> EnvConfig:
        return self.config if self.config is not None else regime_config(self.regime)


def _row_transforms(spec: RLEnvSpec, estimator: WindEstimator | None, rows: slice | None = None) -> list[Transform]:
    """The transforms that work row by row (episode control, wind estimate, observation): they
    may run in a collection worker that holds ``rows`` of the batch (None: all of them)."""
    cfg = spec.env_config
    source = "truth" if spec.wind_input == "truth" else "estimate"
    base_wind = [BaseWindInput(spec.base_wind_input)] if cfg.controller.needs_wind else []
    return [
        EpisodeControl(spec.desync_steps, seed=spec.seed, align=cfg.timing.decisions_per_log, rows=rows),
        WindEstimate(estimator if source == "estimate" else None, EMAConfig(tau_s=spec.ema_tau_s), source=source, config=cfg,
                     every_s=spec.estimate_every_s),
        *base_wind,
        *([ReferenceAhead(cfg.timing.control_dt_s)] if spec.preview_inputs else []),
        PolicyObservation(cfg, base_channels=spec.base_state_inputs, preview_channels=spec.preview_inputs),
        *([PrivilegedObservation(spec.privileged_inputs)] if spec.privileged_inputs else []),
    ]


def _batch_transforms(spec: RLEnvSpec) -> list[Transform]:
    """The transforms that pool the whole batch (the running normalisation) or come after it: they
    stay in the process that runs the policy."""
    transforms = [RunningObsNorm(in_keys=[OBSERVATION_KEY], decay=1.0, eps=1e-4, reduce_batch_dims=True)]
    if spec.obs_clip is not None:
        transforms.append(ClipTransform(in_keys=[OBSERVATION_KEY], low=-spec.obs_clip, high=spec.obs_clip))
    if spec.zeroed_channels:  # one transform, last of the per-frame ones: every other input stays bit-identical
        transforms.append(ZeroInputs(spec.zeroed_channels))
    if spec.memory_frames > 1:  # the stack holds the policy's inputs as it reads them: normalised, clipped, zeroed
        transforms.append(ObservationStack(spec.memory_frames))
    if spec.recurrent_hidden:  # episode starts, and the hidden state the actor carries (0 at a reset)
        transforms += [InitTracker(), TensorDictPrimer({RECURRENT_KEY: Unbounded(shape=(1, spec.recurrent_hidden))},
                                                       expand_specs=True)]
    if spec.privileged_inputs:  # the critic's own normalisation (saved in training checkpoints, never in a policy)
        transforms.append(RunningObsNorm(in_keys=[PRIVILEGED_KEY], decay=1.0, eps=1e-4, reduce_batch_dims=True))
        if spec.obs_clip is not None:
            transforms.append(ClipTransform(in_keys=[PRIVILEGED_KEY], low=-spec.obs_clip, high=spec.obs_clip))
    return transforms + [RewardSum(in_keys=["reward"], out_keys=["episode_reward"], reset_keys=["_reset"]), StepCounter()]


def _base_env(spec: RLEnvSpec, rows: slice | None = None, controller: BaseController | None = None) -> QuadWindEnv:
    sampler = ScenarioSampler(
        ranges=spec.ranges if spec.ranges is not None else DEFAULT_RANGES[spec.regime],
        trajectories=tuple(spec.trajectories) if spec.trajectories is not None else DEFAULT_TRAJECTORIES[spec.regime],
        start=spec.start,
    )
    rows = rows or slice(0, spec.num_envs)
    return QuadWindEnv(spec.env_config, batch_size=[rows.stop - rows.start], device=spec.device, scenario_sampler=sampler,
                       seed=spec.seed, compile_step=spec.compile_step, first_row=rows.start, controller=controller)


class RowWorkerEnv(TransformedEnv):
    """One collection worker's rows with the row-wise transforms; the parent reaches its methods
    through ``ParallelEnv`` (``env.base_env.set_trajectories(...)`` runs in every worker)."""

    def set_trajectories(self, trajectories: tuple[str, ...], truncate: bool) -> None:
        set_trajectories(self, trajectories, truncate)

    def estimator_seconds(self) -> float:
        return wind_estimate(self).estimator_seconds


def _row_worker(spec: RLEnvSpec, estimator: WindEstimator | None, rows: slice, threads: int) -> RowWorkerEnv:
    torch.set_num_threads(threads)
    # the parent gets what the policy and the trainer read (the observation, reward and ends): every
    # entry a worker returns is copied through shared memory at every step, and the full record
    # (sensors, truth, navigation, ...) cost the parent 6-9 ms a step (docs/benchmarks.md)
    keep = SelectTransform(OBSERVATION_KEY, *([PRIVILEGED_KEY] if spec.privileged_inputs else []), keep_rewards=True,
                           keep_dones=True)
    return RowWorkerEnv(_base_env(spec, rows), Compose(*_row_transforms(spec, estimator, rows), keep, RemoveEmptySpecs()))


def build_env(
    spec: RLEnvSpec,
    estimator: WindEstimator | None,
    *,
    vecnorm_state: dict | None = None,
    freeze_norm: bool | None = None,
    workers: int = 1,
    workers_on: WorkersOn = "local",
    controller: BaseController | None = None,
) -> TransformedEnv:
    """The transformed env of ``spec`` (see the module docstring for the stack).

    Args:
        spec: the env's settings.
        estimator: the frozen wind estimator (may be None for ``wind_input="truth"``).
        vecnorm_state: a saved ``VecNormV2`` state dict (``vecnorm_state_dict(env)``) to load.
        freeze_norm: freeze the normalisation statistics (default: frozen iff ``vecnorm_state``).
        workers: collection processes (one per core). With more than one, each single-threaded
            worker holds ``num_envs / workers`` rows with the row-wise transforms (simulator,
            episode control, wind estimate, observation) and this process keeps the rest (the
            normalisation pools every row); the batch is ``[workers, num_envs / workers]`` and
            its rows fly exactly the episodes of the one-process env. The workers return what the
            policy and the trainer read: the observation, the reward and the done flags.
        workers_on: where the workers run: "local" (processes of this machine, one per core) or
            "ray" (Ray actors of 1 CPU each, on any node of the Ray cluster this process has joined;
            the same row split, so the same batch as local workers, bit for bit; also with
            ``workers=1``: all rows in one actor). The rows then fly on the CPU.
        controller: a base controller object instead of the one the config chooses (one process
            only; e.g. a validation search flying a gain per row,
            :mod:`quadwind_trl.studies.base_search`).
    """
    if controller is not None and (workers != 1 or workers_on != "local"):
        raise ValueError(f"build_env: a controller object flies in one process; got workers={workers}, "
                         f"workers_on={workers_on!r}")
    if workers_on not in WORKERS_ON:
        raise ValueError(f"build_env: workers_on={workers_on!r}; allowed: {WORKERS_ON}")
    if workers_on == "ray" and torch.device(spec.device).type != "cpu":
        raise ValueError(f"build_env: workers_on='ray' flies the rows on the CPU; got RLEnvSpec.device={spec.device!r}")
    if spec.wind_input != "truth" and estimator is None:
        raise ValueError(f"wind_input={spec.wind_input!r} needs an estimator")
    if estimator is not None and estimator.schema != spec.regime:
        raise ValueError(f"the estimator was trained on the {estimator.schema!r} schema, not {spec.regime!r}")
    if workers < 1 or spec.num_envs % workers:
        raise ValueError(f"workers={workers}; allowed: >= 1 and dividing RLEnvSpec.num_envs={spec.num_envs}")
    if workers == 1 and workers_on == "local":
        env = TransformedEnv(_base_env(spec, controller=controller),
                             Compose(*_row_transforms(spec, estimator), *_batch_transforms(spec)))
    else:
        n = spec.num_envs // workers
        # the estimator travels to the workers pickled, so every worker flies this very network
        makers = [partial(_row_worker, spec, estimator, slice(i * n, (i + 1) * n), 1) for i in range(workers)]
        rows = QuietParallelEnv(workers, makers) if workers_on == "local" else RayRowsEnv(makers, num_cpus=1)
        env = TransformedEnv(rows, Compose(*_batch_transforms(spec)))
    if vecnorm_state is not None:
        load_vecnorm_state(env, vecnorm_state)
    if freeze_norm or (freeze_norm is None and vecnorm_state is not None):
        vecnorm(env).freeze()
    return env


def make_env(
    regime: Regime,
    estimator: WindEstimator | None,
    num_envs: int,
    *,
    vecnorm_state: dict | None = None,
    freeze_norm: bool | None = None,
    **settings,
) -> TransformedEnv:
    """``build_env(RLEnvSpec(regime, num_envs, **settings), estimator, ...)``: ``settings`` are
    :class:`RLEnvSpec` fields (``wind_input``, ``config``, ``ema_tau_s``, ...)."""
    unknown = sorted(set(settings) - set(RLEnvSpec.__dataclass_fields__))
    if unknown:
        raise TypeError(f"make_env: unknown settings {unknown}; allowed: the RLEnvSpec fields {sorted(RLEnvSpec.__dataclass_fields__)}")
    spec = RLEnvSpec(regime=regime, num_envs=num_envs, **settings)
    return build_env(spec, estimator, vecnorm_state=vecnorm_state, freeze_norm=freeze_norm)


def validated_tau_s(estimator: WindEstimator | None) -> float:
    """The EMA time constant a new policy trains with: the one chosen on the estimator's
    validation flights (``evaluation.val_best_tau_s`` in its checkpoint's manifest, written by
    ``recipes/evaluate_estimator.py --update-checkpoint``), else the paper's
    :data:`~quadwind_trl.estimator.DEFAULT_TAU_S` (unevaluated or untrained estimators)."""
    manifest = getattr(estimator, "manifest", None) or {}
    chosen = manifest.get("evaluation", {}).get("val_best_tau_s")
    return DEFAULT_TAU_S if chosen is None else float(chosen)


# the training recipes query the estimator at most every tau / 30 (docs/rl.md, "How often the
# estimator runs": at tau = 30 s, every 1 s moved the ablation's figures by 0.1 point)
ESTIMATE_EVERY_TAU_FRACTION = 30.0


def recipe_estimate_every_s(tau_s: float, log_dt_s: float) -> float:
    """Seconds between estimator queries the PPO recipes train with by default: the largest whole
    multiple of the log interval ``log_dt_s`` at or below ``tau_s`` / 30, at least one interval (every
    tick for a fast or no EMA)."""
    ticks = max(1, math.floor(tau_s / ESTIMATE_EVERY_TAU_FRACTION / log_dt_s + 1e-9))
    return round(ticks * log_dt_s, 9)


def policy_env_settings(env_spec: Mapping, estimator: WindEstimator | None) -> dict:
    """The :class:`RLEnvSpec` settings a saved policy trained with and must fly with, from its
    checkpoint's ``env_spec``, as ``make_env`` keywords: ``ema_tau_s``, ``estimate_every_s``,
    ``zero_inputs``, ``base_wind_input``, ``base_state_inputs``, ``preview_inputs``, ``memory_frames``
    and ``recurrent_hidden`` (never ``privileged_inputs``: the critic's, at training time only).
    Policies saved before the spec recorded a setting trained with: the tau their estimator's
    checkpoint held (the env then read it from there; else the default), the estimator at every log
    tick, no zeroed inputs, no base state, no preview, no memory."""
    tau = env_spec["ema_tau_s"] if "ema_tau_s" in env_spec else getattr(estimator, "ema_tau_s", None)
    return {
        "ema_tau_s": DEFAULT_TAU_S if tau is None else float(tau),
        "estimate_every_s": float(env_spec.get("estimate_every_s", DEFAULT_ESTIMATE_EVERY_S)),
        "zero_inputs": tuple(env_spec.get("zero_inputs", ())),
        "base_wind_input": env_spec.get("base_wind_input", "estimate"),
        "base_state_inputs": tuple(env_spec.get("base_state_inputs", ())),
        "preview_inputs": tuple(env_spec.get("preview_inputs", ())),
        "memory_frames": int(env_spec.get("memory_frames", 1)),
        "recurrent_hidden": int(env_spec.get("recurrent_hidden", 0)),
    }


def _on_workers(env: TransformedEnv, method: str, *args) -> list | None:
    """``RowWorkerEnv.<method>(*args)`` in each collection worker of ``env``, local or on Ray, their
    answers in row order; None for a one-process env."""
    base = env.base_env
    if isinstance(base, ParallelEnv):
        return getattr(base, method)(*args)
    if isinstance(base, RayRowsEnv):
        return base.call(method, *args)
    return None


def set_trajectories(env: TransformedEnv, trajectories: tuple[str, ...], truncate: bool) -> None:
    """Sample the training episodes that start from now on among ``trajectories`` (a curriculum
    stage); with ``truncate``, end every running episode at the next step so the set takes effect
    at once. Works on a one-process env and on one with collection workers (in each of them)."""
    if _on_workers(env, "set_trajectories", tuple(trajectories), truncate) is not None:
        return
    base = env.base_env
    base.scenario_sampler = replace(base.scenario_sampler, trajectories=tuple(trajectories))
    if truncate:
        episode_control(env).request_truncation()


def estimator_seconds(env: TransformedEnv) -> float:
    """Seconds the env's wind estimator has run so far (summed over collection workers; they run
    at the same time); raises ``KeyError`` when the env has no ``WindEstimate``."""
    seconds = _on_workers(env, "estimator_seconds")
    if seconds is not None:
        return float(sum(seconds))
    return wind_estimate(env).estimator_seconds


def find_transform(env: TransformedEnv, cls: type[T]) -> T:
    """The first transform of type ``cls`` in ``env``'s stack."""
    for t in env.transform:
        if isinstance(t, cls):
            return t
    raise KeyError(f"no {cls.__name__} in this env's transforms")


def vecnorm(env: TransformedEnv, key: str = OBSERVATION_KEY) -> VecNormV2:
    """The running normalisation of ``key`` (the policy's ``observation``; ``keys.PRIVILEGED_KEY``:
    the asymmetric critic's)."""
    for t in env.transform:
        if isinstance(t, VecNormV2) and key in t.in_keys:
            return t
    raise KeyError(f"no VecNormV2 of {key!r} in this env's transforms")


def episode_control(env: TransformedEnv) -> EpisodeControl:
    return find_transform(env, EpisodeControl)


def wind_estimate(env: TransformedEnv) -> WindEstimate:
    return find_transform(env, WindEstimate)


def vecnorm_state_dict(env: TransformedEnv, key: str = OBSERVATION_KEY) -> dict:
    """The normalisation statistics of ``key`` (a plain, ``torch.load(weights_only=True)``-able dict)."""
    return dict(vecnorm(env, key).state_dict())


def load_vecnorm_state(env: TransformedEnv, state: dict, key: str = OBSERVATION_KEY) -> None:
    vecnorm(env, key).load_state_dict(state)


@dataclass
class EnvFactory:
    """Picklable env constructor: ``EnvFactory(spec)()`` is ``build_env(spec, estimator)``;
    keyword overrides replace spec fields (``vecnorm_state`` / ``freeze_norm`` go to ``build_env``).

    ``bundle`` may be given to share an already loaded estimator in-process (it is dropped when
    the factory is pickled: other processes load it from ``spec.estimator_path``)."""

    spec: RLEnvSpec
    bundle: WindEstimator | None = field(default=None, repr=False)

    def __getstate__(self):
        return {"spec": self.spec, "bundle": None}

    def estimator(self) -> WindEstimator | None:
        s = self.spec
        if s.wind_input == "truth" and s.estimator_path is None and not s.untrained_estimator:
            return None
        if self.bundle is None:
            self.bundle = load_estimator(
                s.regime, s.estimator_path, untrained=s.untrained_estimator, config=s.env_config, device=s.device
            )
        return self.bundle

    def __call__(self, **overrides) -> TransformedEnv:
        fields = RLEnvSpec.__dataclass_fields__
        spec = replace(self.spec, **{k: v for k, v in overrides.items() if k in fields})
        return build_env(spec, self.estimator(), **{k: v for k, v in overrides.items() if k not in fields})


__all__ = [
    "EnvFactory",
    "RLEnvSpec",
    "build_env",
    "make_env",
    "policy_env_settings",
    "validated_tau_s",
    "find_transform",
    "vecnorm",
    "vecnorm_state_dict",
    "load_vecnorm_state",
    "episode_control",
    "wind_estimate",
    "set_trajectories",
    "estimator_seconds",
    "RowWorkerEnv",
]
