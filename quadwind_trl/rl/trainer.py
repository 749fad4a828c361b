"""The PPO trainer: collect a batch -> update -> (periodically) evaluate against PD -> checkpoint.

Each piece is its own method; :meth:`PPOTrainer.train` is the loop calling them. The update is
:class:`~quadwind_trl.rl.update.PPOUpdate`, the evaluation is
:func:`~quadwind_trl.rl.evaluator.evaluate_against_pd` (flown through
:func:`~quadwind_trl.rl.paired.fly_paired`, as the ablation is), in this process or, with
``PPOConfig.background_eval``, in a second one while training goes on
(:class:`~quadwind_trl.rl.evaluator.BackgroundEvaluator`: the run records each result when it
arrives, its checkpoints hold the evaluations still in flight, and its end waits for them). The
policy file format is :func:`~quadwind_trl.rl.policy.policy_payload`. Settings:
:class:`~quadwind_trl.rl.config.PPOConfig`.
"""
from __future__ import annotations

import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable

import torch
from tensordict import TensorDictBase
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import ExplorationType
from torchrl.record.loggers import Logger

from ..config import EnvConfig, config_differences, config_from_dict
from ..estimator import WindEstimator
from ..manifest import command_line, git_commit, platform_info, repo_relative, save_atomic, write_json
from ..outputs import OutputLock, truncate_scalar_logs
from ..keys import PRIVILEGED_KEY
from . import collection
from .config import Curriculum, PPOConfig
from .envs import (EnvFactory, RLEnvSpec, estimator_seconds, load_vecnorm_state, policy_env_settings, set_trajectories,
                   vecnorm_state_dict)
from .evaluator import BackgroundEvaluator, evaluate_against_pd, from_bytes, to_bytes
from .paired import VALIDATION_TAIL_FRACTION
from .policy import action_scale, build_actor_critic, check_recurrent, network_dims, policy_payload, spec_to_dict
from .update import PPOUpdate


# PPOConfig fields a resumed run may change: how long it runs, how often it evaluates and
# checkpoints, and its threads and processes; any other change would make it another recipe
RESUMABLE_CHANGES = ("total_frames", "eval_every_frames", "checkpoint_every_frames", "threads", "update_threads",
                     "collect_workers", "collector", "num_collectors", "ray_address", "background_eval")
# what runs saved before a PPOConfig field existed used (their checkpoints lack it)
SAVED_BEFORE_FIELD = {"lr_schedule": "constant", "reward_scaling": "none", "value_norm": False}


class ResumeMismatch(ValueError):
    """A resumed run's PPO settings, or its policy's inputs, differ from its checkpoint's."""


def check_same_recipe(saved: dict, cfg: PPOConfig) -> None:
    """Refuse to resume a checkpoint saved with ``saved`` (its ``ppo_config``) under ``cfg`` when
    they differ in anything but :data:`RESUMABLE_CHANGES`, naming the field and both values."""
    saved = {**SAVED_BEFORE_FIELD, **saved}
    for name, value in asdict(cfg).items():
        if name in RESUMABLE_CHANGES or name not in saved:
            continue
        before = saved[name]
        if (list(before) if isinstance(before, (list, tuple)) else before) != (list(value) if isinstance(value, tuple) else value):
            raise ResumeMismatch(f"resume: PPOConfig.{name}={value!r} but the checkpoint's run used {before!r}; "
                                 f"resume with the run's settings (e.g. --{name.replace('_', '-')} {before}) or start a new --out")


def check_same_env(saved: dict, spec: RLEnvSpec, estimator: WindEstimator | None) -> None:
    """Refuse to resume a checkpoint whose env spec (``saved``) gave the policy other inputs than
    ``spec`` would: another wind input or another :func:`~quadwind_trl.rl.envs.policy_env_settings`
    (EMA tau, estimator interval, zeroed inputs), naming the setting and both values; or another
    env config (vehicle, sensing, reward, ...), naming its differing fields."""
    differ = config_differences(config_from_dict(EnvConfig, saved["env_config"]), spec.env_config)
    if differ:
        raise ResumeMismatch(f"resume: the env config differs from the checkpoint's run in {', '.join(differ)} "
                             "(e.g. --sensing, --reward-w-z); resume with the run's settings or start a new --out")
    before = {"wind_input": saved.get("wind_input"), "privileged_inputs": tuple(saved.get("privileged_inputs", ())),
              **policy_env_settings(saved, estimator)}
    now = {"wind_input": spec.wind_input, "privileged_inputs": spec.privileged_inputs,
           **policy_env_settings(spec_to_dict(spec), estimator)}
    for name, value in now.items():
        # zeroed inputs are a set: the order they were named in changes nothing
        same = set(value) == set(before[name]) if name == "zero_inputs" else value == before[name]
        if not same:
            raise ResumeMismatch(f"resume: RLEnvSpec.{name}={value!r} but the checkpoint's run used {before[name]!r}; "
                                 f"resume with the run's settings (--{name.replace('_', '-')}) or start a new --out")


SELECTION_RULE = (f"the policy of the evaluation with the lowest validation score: mean episode RMSE + mean RMSE of the "
                  f"worst {VALIDATION_TAIL_FRACTION:.0%} of episodes, on the regime's validation sweep; the last iterate "
                  "when the run evaluates nothing")


def episode_steps_hint(spec: RLEnvSpec) -> int:
    """Mean episode length (env steps) of ``spec``'s training trajectories: the range of the
    first-episode de-synchronisation."""
    from ..envs.simulator import trajectory_library
    from ..envs.trajectories import trajectory_ids
    from .envs import DEFAULT_RANGES, DEFAULT_TRAJECTORIES

    traj = spec.trajectories or DEFAULT_TRAJECTORIES[spec.regime]
    ranges = spec.ranges or DEFAULT_RANGES[spec.regime]
    alt = 0.5 * sum(ranges.altitude_m) if ranges.altitude_m is not None else ranges.top_altitude_m
    ids = trajectory_ids(traj)
    start, end = trajectory_library(spec.env_config, "cpu").schedule(ids, torch.full((len(traj),), float(alt)))
    steps = end - start if spec.start == "pattern" else end
    return max(1, int(steps.float().mean()) // spec.env_config.timing.hold_control_steps)


@dataclass
class PPOResult:
    """What :meth:`PPOTrainer.train` returns (the files it wrote are in ``out_dir``)."""

    out_dir: Path
    frames: int
    iterations: int
    history: list[dict] = field(default_factory=list)  # per-iteration training metrics (this session)
    evals: list[dict] = field(default_factory=list)  # every evaluation of the run
    wall_time_s: float = 0.0


@dataclass
class Progress:
    """The run's counters, saved in every checkpoint (``progress``) so a resumed run continues them."""

    frames: int = 0
    iteration: int = 0
    stage: int = 0  # curriculum stage
    pd_eval: dict | None = None  # PD's per-episode evaluation results, flown once (the same every time)
    wall: float = 0.0  # s of training over all sessions
    evals: list[dict] = field(default_factory=list)
    last_eval_frames: int = 0
    last_ckpt_frames: int = 0
    best: dict | None = None  # the evaluation the kept policy comes from (checkpoints/best.pt)


@dataclass
class _Session:
    """What one call of :meth:`PPOTrainer.train` works on."""

    learner: PPOUpdate
    env: TransformedEnv
    eval_env: TransformedEnv | None  # the evaluation's env, in this process (None: none, or in the background)
    evaluator: BackgroundEvaluator | None  # PPOConfig.background_eval
    progress: Progress
    logger: Logger
    result: PPOResult
    wall0: float  # perf_counter() at which the run's wall time would have been 0
    # background evaluations in flight: the snapshot's frames -> (iteration, its policy file as bytes)
    in_flight: dict[int, tuple[int, bytes]] = field(default_factory=dict)
    stop: bool = False  # stop_when said so

    def tick(self) -> float:
        """Update and return the run's wall time."""
        self.progress.wall = time.perf_counter() - self.wall0
        return self.progress.wall


class PPOTrainer:
    """Collect -> GAE -> 10 epochs of minibatch ClipPPO updates, with periodic deterministic
    evaluation against PD, CSV (or TensorBoard) logs, checkpoints and resume.

    Output directory::

        OUT/config.json                 the run's PPO config and env spec
        OUT/logs/<exp>/scalars/*.csv    TorchRL CSVLogger (TensorBoard with logger="tensorboard")
        OUT/checkpoints/latest.pt       policy, value, optimiser, VecNorm stats, RNG, progress
        OUT/checkpoints/latest.json     its manifest
        OUT/checkpoints/best.pt         the policy of the best evaluation so far (SELECTION_RULE)
        OUT/policy.pt, OUT/policy.json  the kept policy + frozen normalisation + manifest: the best
                                        evaluated one, or the last iterate when nothing is evaluated
    """

    def __init__(
        self,
        env_spec: RLEnvSpec,
        cfg: PPOConfig,
        out_dir: str | Path,
        *,
        eval_scenarios: TensorDictBase | None = None,
        curriculum: Curriculum | None = None,
        logger: str = "csv",
        progress: bool = True,
        command: str | None = None,
        estimator_bundle=None,
        on_iteration: Callable[[dict], None] | None = None,
        stop_when: Callable[[list[dict]], bool] | None = None,
    ):
        self.cfg = cfg.validate()
        check_recurrent(self.cfg, env_spec)
        if env_spec.num_envs != cfg.num_envs:
            env_spec = replace(env_spec, num_envs=cfg.num_envs)
        self.spec = env_spec
        # the evaluations fly the policy as every later flight does: without the critic's privileged inputs
        self.eval_spec = replace(env_spec, privileged_inputs=())
        self.out_dir = Path(out_dir)
        self.eval_scenarios = eval_scenarios
        self.curriculum = curriculum
        self.logger_kind = logger
        self.progress = progress
        self.command = command if command is not None else command_line(sys.argv)
        self.factory = EnvFactory(env_spec, bundle=estimator_bundle)
        self.on_iteration = on_iteration
        self.stop_when = stop_when  # called with the evaluations after each one: True ends the run there
        self._collection: dict = collection.describe(self.cfg)  # where the rows run (_start adds the Ray nodes)

    @property
    def checkpoint_path(self) -> Path:
        return self.out_dir / "checkpoints" / "latest.pt"

    @property
    def best_path(self) -> Path:
        return self.out_dir / "checkpoints" / "best.pt"

    # --- the loop ------------------------------------------------------------------------------

    def train(self, resume: bool = False) -> PPOResult:
        """Train to ``cfg.total_frames`` (whole batches), from ``checkpoints/latest.pt`` with
        ``resume``; writes the files listed above and returns the run's :class:`PPOResult`."""
        if self.cfg.threads:
            torch.set_num_threads(self.cfg.threads)
        # one writer per run directory: a second run on it (a resume included) is refused at once
        with OutputLock(self.out_dir, "training run", "wait for it to finish, or choose another out_dir (--out)"), \
                collection.connected(self.cfg) as where:
            if where and self.progress:
                print(f"collection: {self.cfg.num_collectors} Ray actors on {where}", flush=True)
            session = self._start(self._check_resume(resume))
            try:
                if session.progress.frames < self.cfg.planned_frames:
                    self._collect_and_update(session)
            finally:
                if session.evaluator is not None:
                    session.evaluator.close()
            return self._finish(session)

    def _collect_and_update(self, s: _Session) -> None:
        from torchrl.collectors import Collector
        from tqdm.auto import tqdm

        cfg = self.cfg
        # endless (-1): the loop below ends the run. A collector that counts the frames itself closes
        # a multi-process env before it hands over the last batch, whose logging still asks the workers
        collector = Collector(s.env, s.learner.actor, frames_per_batch=cfg.frames_per_batch, total_frames=-1,
                              exploration_type=ExplorationType.RANDOM, auto_register_policy_transforms=False)
        bar = tqdm(total=cfg.planned_frames, initial=s.progress.frames, unit="frame", unit_scale=True,
                   disable=not self.progress, desc="ppo")
        gen = torch.Generator().manual_seed(cfg.seed * 1000 + s.progress.iteration)
        t_collect0 = time.perf_counter()
        try:
            for data in collector:
                metrics = self._iteration(s, data, gen, collect_s=time.perf_counter() - t_collect0)
                bar.update(data.numel())
                bar.set_postfix(r=f"{metrics['reward_mean']:.3f}", ret=f"{metrics.get('episode_return', float('nan')):.0f}")
                if self.on_iteration is not None:
                    self.on_iteration(metrics)
                if self._evaluation_due(s):
                    self._evaluate(s)
                if s.evaluator is not None:
                    # the run's last checkpoint holds every evaluation: at its end, wait for those in flight
                    self._receive_evaluations(s, wait=self._finished(s.progress))
                    if s.stop:
                        self._receive_evaluations(s, wait=True)
                if s.stop or self._checkpoint_due(s):
                    self._checkpoint(s)
                if s.stop or self._finished(s.progress):
                    break
                t_collect0 = time.perf_counter()
        finally:
            bar.close()
            collector.shutdown()

    # --- pieces -------------------------------------------------------------------------------

    def _check_resume(self, resume: bool) -> bool:
        latest = self.checkpoint_path
        if latest.exists() and not resume:
            raise FileExistsError(f"{latest} exists: pass --resume to continue that run, or choose another --out")
        if resume and not latest.exists():
            # resumable stages (reproduce.py) always pass --resume: nothing to resume is a fresh start
            print(f"--resume: no checkpoint at {latest}; starting a new run", flush=True)
            resume = False
        latest.parent.mkdir(parents=True, exist_ok=True)
        return resume

    def _start(self, resume: bool) -> _Session:
        """Networks, optimiser, envs and logger, from the checkpoint when resuming (the order of
        the seeded steps is the run's: a resumed run repeats the same random streams)."""
        cfg, spec = self.cfg, self.spec
        torch.manual_seed(cfg.seed)
        actor, value = build_actor_critic(cfg, **network_dims(spec))
        learner = PPOUpdate(actor.to(spec.device), value.to(spec.device), cfg)
        progress = Progress()
        checkpoint = None
        if resume:
            checkpoint = torch.load(self.checkpoint_path, weights_only=True)
            check_same_recipe(checkpoint["ppo_config"], cfg)
            check_same_env(checkpoint["env_spec"], spec, self.factory.estimator())
            learner.load_state_dict(checkpoint)
            progress = Progress(**checkpoint["progress"])
            torch.random.set_rng_state(checkpoint["rng"])
        else:
            write_json(self.out_dir / "config.json", {"ppo_config": asdict(cfg), "env_spec": spec_to_dict(spec),
                                                      "curriculum": asdict(self.curriculum) if self.curriculum else None,
                                                      "command": self.command})
        # the training env: a fresh seed per (resumed) segment so episodes do not repeat
        env = self.factory(seed=spec.seed + 7919 * progress.iteration,
                           desync_steps=episode_steps_hint(spec) if cfg.desync else 0, **collection.env_layout(cfg))
        self._collection = collection.describe(cfg, env)
        network = getattr(self.factory.bundle, "model", None)  # a WindEstimator need not be a network
        if network is not None:
            learner.check_frozen(network)
        if checkpoint is not None:
            load_vecnorm_state(env, checkpoint["vecnorm"])
            if spec.privileged_inputs:
                load_vecnorm_state(env, checkpoint["privileged_vecnorm"], PRIVILEGED_KEY)
        if self.curriculum is not None:
            self._apply_stage(env, progress.stage, truncate=False)
        eval_env = evaluator = None
        eval_factory = EnvFactory(self.eval_spec, bundle=self.factory.estimator())
        if self.eval_scenarios is not None and cfg.background_eval:
            evaluator = BackgroundEvaluator(eval_factory, self.eval_scenarios, cfg, seed=spec.seed + 1)
        elif self.eval_scenarios is not None:
            eval_env = eval_factory(num_envs=self.eval_scenarios.batch_size[0], seed=spec.seed + 1, desync_steps=0)
        result = PPOResult(self.out_dir, progress.frames, progress.iteration, evals=list(progress.evals))
        s = _Session(learner, env, eval_env, evaluator, progress, self._make_logger(progress), result,
                     wall0=time.perf_counter() - progress.wall)
        # evaluations in flight when the checkpoint was written are flown again, in this session's
        # evaluation process (or here)
        for job in (checkpoint or {}).get("evals_in_flight", []):
            self._evaluate(s, job["frames"], job["iteration"], job["policy"])
        return s

    def _iteration(self, s: _Session, data: TensorDictBase, gen: torch.Generator, collect_s: float) -> dict:
        """Update on one collected batch; advance the counters and the curriculum; log."""
        t0 = time.perf_counter()
        data = data.reshape(-1, data.shape[-1])  # [workers, rows, T] with collection workers: [N, T]
        stats = self._episode_stats(data)
        threads = torch.get_num_threads()
        torch.set_num_threads(self.cfg.update_threads or threads)
        p = s.progress
        lr = self.cfg.lr_at(p.frames)
        try:
            metrics = s.learner.update(data, gen, lr=lr)
        finally:
            torch.set_num_threads(threads)
        update_s = time.perf_counter() - t0
        p.iteration += 1
        p.frames += data.numel()
        metrics.update(stats)
        metrics.update(frames=p.frames, lr=lr, collect_s=collect_s, update_s=update_s, fps=data.numel() / max(collect_s, 1e-9),
                       action_scale=action_scale(s.learner.actor))
        if self.curriculum is not None:
            metrics["curriculum_stage"] = p.stage
            new_stage = self.curriculum.stage_at(p.frames, self.cfg.total_frames)
            if new_stage != p.stage:
                p.stage = new_stage
                self._apply_stage(s.env, new_stage, truncate=True)
        try:
            metrics["estimator_s"] = estimator_seconds(s.env)
        except KeyError:  # wind_input="truth" without an estimator
            pass
        metrics["wall_s"] = s.tick()
        self._log(s.logger, "train", metrics, p.frames)
        s.result.history.append(metrics)
        return metrics

    def _apply_stage(self, env: TransformedEnv, stage: int, truncate: bool) -> None:
        set_trajectories(env, self.curriculum.stages[stage], truncate)

    @staticmethod
    def _episode_stats(data: TensorDictBase) -> dict[str, float]:
        nxt = data["next"]
        done = nxt["done"].squeeze(-1)
        out = {
            "reward_mean": float(nxt["reward"].mean()),
            "crash_rate_per_kstep": float(1000.0 * nxt["terminated"].float().mean()),
            "episodes_finished": int(done.sum()),
        }
        if bool(done.any()):
            out["episode_return"] = float(nxt["episode_reward"][done].mean())
            out["episode_length"] = float(nxt["step_count"][done].float().mean())
        return out

    def _finished(self, p: Progress) -> bool:
        return p.frames >= self.cfg.planned_frames

    def _evaluation_due(self, s: _Session) -> bool:
        p, every = s.progress, self.cfg.eval_every_frames
        return self.eval_scenarios is not None and (self._finished(p) or (every and p.frames - p.last_eval_frames >= every))

    def _checkpoint_due(self, s: _Session) -> bool:
        p = s.progress
        return self._finished(p) or p.frames - p.last_ckpt_frames >= self.cfg.checkpoint_every_frames

    def _evaluate(self, s: _Session, frames: int | None = None, iteration: int | None = None,
                  policy: bytes | None = None) -> None:
        """The deterministic policy against PD on the evaluation scenarios
        (:func:`~quadwind_trl.rl.evaluator.evaluate_against_pd`), with the training normalisation
        frozen: here, or submitted to the background evaluator (``policy``, ``frames``,
        ``iteration``: a snapshot taken earlier, by default the current one)."""
        p = s.progress
        if frames is None:
            frames, iteration, policy = p.frames, p.iteration, to_bytes(self._policy_file(s))
            p.last_eval_frames = p.frames
        if s.evaluator is None:
            snapshot, actor = from_bytes(policy), s.learner.actor
            if frames != p.frames:  # a snapshot a resumed checkpoint held in flight: its own actor
                with torch.random.fork_rng():  # building it draws initial weights: not from the run's stream
                    actor = build_actor_critic(self.cfg, **network_dims(self.spec))[0].to(self.spec.device)
                actor.load_state_dict(snapshot["policy"])
            metrics, p.pd_eval = evaluate_against_pd(s.eval_env, self.eval_spec, actor, snapshot["vecnorm"], self.eval_scenarios,
                                                     p.pd_eval)
            self._record_evaluation(s, frames, iteration, policy, metrics)
        else:
            s.in_flight[frames] = (iteration, policy)
            s.evaluator.submit(frames, policy, p.pd_eval)

    def _receive_evaluations(self, s: _Session, wait: bool) -> None:
        """Record the background evaluations that have finished (with ``wait``: all of them)."""
        for done in s.evaluator.receive(wait):
            if s.progress.pd_eval is None:
                s.progress.pd_eval = done.pd_eval
            iteration, policy = s.in_flight.pop(done.frames)
            self._record_evaluation(s, done.frames, iteration, policy, done.metrics)

    def _record_evaluation(self, s: _Session, frames: int, iteration: int, policy: bytes, metrics: dict) -> None:
        """Log one evaluation of the snapshot taken at ``frames``, keep its policy if it is the best
        so far (:data:`SELECTION_RULE`), and ask ``stop_when``."""
        p = s.progress
        metrics["frames"] = frames
        p.evals = list(p.evals) + [metrics]
        self._log(s.logger, "eval", metrics, frames)
        if p.best is None or metrics["validation_score"] < p.best["validation_score"]:
            save_atomic(from_bytes(policy), self.best_path)
            p.best = {"frames": frames, "iteration": iteration, "validation_score": metrics["validation_score"]}
        if self.progress:
            print(f"[eval @ {frames} frames] rmse {metrics['rmse']:.3f} m vs the base law alone {metrics['pd_rmse']:.3f} m "
                  f"(RMSE reduction {metrics['improvement_vs_pd']:+.1f} %, positive = better), win rate {metrics['win_rate']:.2f}, "
                  f"crashed {metrics['crashed']}, validation score {metrics['validation_score']:.3f} m"
                  f"{' (best so far)' if p.best['frames'] == frames else ''}, {metrics['eval_s']:.0f} s", flush=True)
        s.stop = s.stop or (self.stop_when is not None and self.stop_when(p.evals))

    def _checkpoint(self, s: _Session) -> None:
        """``checkpoints/latest.pt``: everything :meth:`train` needs to resume, and its manifest."""
        p = s.progress
        p.last_ckpt_frames = p.frames
        s.tick()
        payload = policy_payload(s.learner.actor, vecnorm_state_dict(s.env), self.cfg, self.spec)
        payload.update(s.learner.state_dict(), rng=torch.random.get_rng_state(), progress=asdict(p))
        if self.spec.privileged_inputs:  # the critic's normalisation: a resume needs it, a policy file never
            payload["privileged_vecnorm"] = vecnorm_state_dict(s.env, PRIVILEGED_KEY)
        # background evaluations not yet back: a resumed run flies them again
        payload["evals_in_flight"] = [{"frames": f, "iteration": i, "policy": policy} for f, (i, policy) in s.in_flight.items()]
        save_atomic(payload, self.checkpoint_path)
        write_json(self.checkpoint_path.with_suffix(".json"), self._manifest(p))

    def _policy_file(self, s: _Session) -> dict:
        """What ``policy.pt`` holds: the policy, its frozen normalisation and the critic."""
        payload = policy_payload(s.learner.actor, vecnorm_state_dict(s.env), self.cfg, self.spec)
        payload["value"] = s.learner.value.state_dict()
        return payload

    def _finish(self, s: _Session) -> PPOResult:
        """``policy.pt`` and ``policy.json``: the best evaluated policy (:data:`SELECTION_RULE`),
        or the last iterate when the run evaluates nothing."""
        p = s.progress
        s.tick()
        payload = torch.load(self.best_path, weights_only=True) if p.best is not None else self._policy_file(s)
        save_atomic(payload, self.out_dir / "policy.pt")
        write_json(self.out_dir / "policy.json", self._manifest(p) | {"evals": p.evals})
        r = s.result
        r.frames, r.iterations, r.wall_time_s, r.evals = p.frames, p.iteration, p.wall, list(p.evals)
        return r

    def _make_logger(self, p: Progress) -> Logger:
        """The run's logger; CSV logs keep only the rows up to the checkpoint's ``p`` (nothing for a
        new run): training rows up to its frames, evaluation rows up to its last recorded evaluation
        (a background one recorded after the checkpoint is flown and logged again)."""
        from torchrl.record import CSVLogger

        log_dir = str(self.out_dir / "logs")
        if self.logger_kind == "tensorboard":
            from torchrl.record import TensorboardLogger

            try:
                return TensorboardLogger(exp_name="ppo", log_dir=log_dir)
            except ImportError as err:  # torch.utils.tensorboard needs the tensorboard package
                raise ImportError(f"logger='tensorboard' needs TensorBoard: pip install -e '.[tensorboard]' ({err})") from None
        if self.logger_kind != "csv":
            raise ValueError(f"logger={self.logger_kind!r}; allowed: 'csv', 'tensorboard'")
        last_eval = p.evals[-1]["frames"] if p.evals else -1
        truncate_scalar_logs(Path(log_dir) / "ppo" / "scalars", lambda name: last_eval if name.startswith("eval/") else p.frames)
        return CSVLogger(exp_name="ppo", log_dir=log_dir)

    @staticmethod
    def _log(logger: Logger, prefix: str, metrics: dict, frames: int) -> None:
        for k, v in metrics.items():
            logger.log_scalar(f"{prefix}/{k}", float(v), step=frames)

    def _manifest(self, p: Progress) -> dict:
        est = self.factory.bundle
        return {
            "command": self.command,
            "git_commit": git_commit(),
            "platform": platform_info(),
            "ppo_config": asdict(self.cfg),
            "env_spec": spec_to_dict(self.spec),
            "curriculum": asdict(self.curriculum) if self.curriculum else None,
            "estimator": {"path": None if self.spec.estimator_path is None else repo_relative(self.spec.estimator_path),
                          "untrained": self.spec.untrained_estimator,
                          "manifest": getattr(est, "manifest", None)},
            "observation_channels": list(self.spec.observation_channels),
            "frames": p.frames,
            "iterations": p.iteration,
            "wall_time_s": round(p.wall, 1),
            "torch_threads": torch.get_num_threads(),
            "collection": self._collection,  # this session's: a resume may collect otherwise
            "selection": {"rule": SELECTION_RULE, "evaluations": len(p.evals), **(p.best or {"frames": p.frames})},
            # the evaluation of the kept policy
            "metrics": next((e for e in p.evals if p.best and e["frames"] == p.best["frames"]), {}),
        }
