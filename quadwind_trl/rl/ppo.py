"""PPO for the residual wrench policy, on TorchRL (``Collector``, ``GAE``, ``ClipPPOLoss``).

Paper settings (Section "Policy, observation, and action"; Stable-Baselines3 there) and ours:

==========================  =====================  =============================================
setting                     paper                  here
==========================  =====================  =============================================
actor / critic              MLP 2 x 256            separate MLPs 2 x 256, Tanh (SB3's default)
action distribution         (SB3: diag. Gaussian,  TanhNormal on [-1, 1]^4 (exact log-probs of the
                            clipped to bounds)     bounded action), state-independent scale
learning rate               3e-4                   3e-4 (Adam, eps 1e-5 as SB3)
samples per batch           2048 steps x n_envs    num_envs x steps_per_env = 64 x 256 = 16384
                                                   (= 8 envs x 2048 steps)
minibatch / epochs          512 / 10               512 / 10 (32 minibatches per epoch)
gamma / GAE lambda          0.99 / 0.95            0.99 / 0.95, on [N, T] before flattening,
                                                   once per batch (as SB3)
clip / entropy / value      0.2 / 0.005 / 0.5      ClipPPOLoss(0.2, entropy_coeff=0.005,
                                                   critic_coeff=0.5, loss_critic_type="l2")
advantage normalisation     (SB3 default: yes)     per minibatch
grad-norm clip              0.5                    0.5 (actor + critic parameters together)
observation normalisation   running mean/var,      VecNormV2(decay=1.0: cumulative, as SB3),
                            frozen at evaluation   clipped to +-10, frozen at evaluation
total                       ~3M env steps at       --total-frames: default 1.5M decisions at
                            100 Hz (8.3 h flight)  10 Hz (42 h of flight; docs/rl.md)
==========================  =====================  =============================================

Initialisation follows SB3: orthogonal weights, gain sqrt(2) in the hidden layers, 0.01 on the
action mean (the initial deterministic policy is ~ the PD baseline), 1 on the value output.

The frozen estimator lives in the env's ``WindEstimate`` transform as a plain attribute: the
optimiser is built from ``loss.parameters()`` (actor + critic only), and the trainer checks at
start-up that no estimator parameter is among them.
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Callable, Sequence

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import AddStateIndependentNormalScale, TensorDictModule
from torch import nn
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from ..config import config_to_dict
from ..manifest import command_line, git_commit, save_atomic, write_json
from ..validation import load_checkpoint
from ..envs.runner import fly
from ..evaluation.statistics import improvement, win_rate
from ..transforms import OBSERVATION_CHANNELS, OBSERVATION_DIM
from .envs import EnvFactory, RLEnvSpec, episode_control, load_vecnorm_state, vecnorm, vecnorm_state_dict, wind_estimate

CHECKPOINT_FORMAT = 1
ACTIVATIONS = {"tanh": nn.Tanh, "elu": nn.ELU, "relu": nn.ReLU}


@dataclass(frozen=True)
class PPOConfig:
    total_frames: int = 1_500_000  # decisions at 10 Hz; paper: ~3M env steps at 100 Hz (docs/rl.md)
    num_envs: int = 64
    steps_per_env: int = 256  # frames per batch = num_envs * steps_per_env (paper: 2048 per env)
    epochs: int = 10  # paper
    minibatch: int = 512  # paper
    lr: float = 3e-4  # paper
    clip_epsilon: float = 0.2  # paper
    entropy_coeff: float = 0.005  # paper
    critic_coeff: float = 0.5  # paper
    gamma: float = 0.99  # paper
    lmbda: float = 0.95  # paper
    max_grad_norm: float = 0.5  # paper
    hidden: tuple[int, ...] = (256, 256)  # paper
    activation: str = "tanh"
    init_scale: float = 0.5  # initial std of the pre-tanh Normal (ours; SB3 uses 1.0)
    loss_critic_type: str = "l2"  # SB3: MSE
    normalize_advantage: bool = True  # SB3 default
    seed: int = 0
    desync: bool = True  # truncate each row's first episode at a random length (EpisodeControl)
    eval_every_frames: int = 500_000  # 0: only at the end
    checkpoint_every_frames: int = 250_000
    threads: int | None = 1

    @property
    def frames_per_batch(self) -> int:
        return self.num_envs * self.steps_per_env

    @property
    def iterations(self) -> int:
        return max(1, math.ceil(self.total_frames / self.frames_per_batch))

    def validate(self) -> "PPOConfig":
        if self.frames_per_batch % self.minibatch:
            raise ValueError(
                f"PPOConfig: num_envs * steps_per_env = {self.frames_per_batch} must be a multiple of minibatch={self.minibatch}"
            )
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"PPOConfig.activation={self.activation!r}; allowed: {sorted(ACTIVATIONS)}")
        for name in ("num_envs", "steps_per_env", "epochs", "minibatch", "total_frames"):
            if getattr(self, name) < 1:
                raise ValueError(f"PPOConfig.{name}={getattr(self, name)} must be >= 1")
        if not 0 < self.init_scale:
            raise ValueError(f"PPOConfig.init_scale={self.init_scale} must be > 0")
        return self


@dataclass(frozen=True)
class Curriculum:
    """Trajectory stages switched by training progress.

    Stage ``k`` (0-based) starts at ``starts[k] * total_frames`` and samples its episodes among
    ``stages[k]``. The vertical curriculum (:func:`vertical_curriculum`) is cumulative: stage k
    samples uniformly among the first k+1 trajectories. When a stage starts, running episodes are
    truncated (bootstrapped) so the new set takes effect at once.
    """

    stages: tuple[tuple[str, ...], ...]
    starts: tuple[float, ...]

    def __post_init__(self):
        if len(self.stages) != len(self.starts) or not self.stages:
            raise ValueError("Curriculum: one start fraction per stage")
        if self.starts[0] != 0.0 or list(self.starts) != sorted(self.starts) or self.starts[-1] >= 1.0:
            raise ValueError(f"Curriculum.starts={self.starts} must start at 0, increase and stay below 1")

    def stage_at(self, frames: int, total_frames: int) -> int:
        frac = frames / max(total_frames, 1)
        return max(k for k, s in enumerate(self.starts) if frac >= s - 1e-12)


def vertical_curriculum(trajectories: Sequence[str] | None = None) -> Curriculum:
    """The paper's four stages: vertical_climb -> + spiral_ascent -> + figure8_3d -> +
    lawnmower_scan, each starting after another quarter of the frames (cumulative sets)."""
    from ..envs.trajectories import VERTICAL

    traj = tuple(trajectories or VERTICAL)
    k = len(traj)
    return Curriculum(stages=tuple(traj[: i + 1] for i in range(k)), starts=tuple(i / k for i in range(k)))


# --- networks -------------------------------------------------------------------------------


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


def build_actor_critic(cfg: PPOConfig, obs_dim: int = OBSERVATION_DIM, action_dim: int = 4,
                       action_low: float = -1.0, action_high: float = 1.0) -> tuple[ProbabilisticActor, ValueOperator]:
    """TanhNormal actor (``observation`` -> ``action``, ``action_log_prob``) and value critic."""
    act = ACTIVATIONS[cfg.activation]
    sizes = (obs_dim, *cfg.hidden)
    net = nn.Sequential(
        _mlp((*sizes, action_dim), act, 0.01),
        AddStateIndependentNormalScale(action_dim, scale_mapping="exp", init_value=math.log(cfg.init_scale)),
    )
    actor = ProbabilisticActor(
        TensorDictModule(net, in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": action_low, "high": action_high},
        return_log_prob=True,
        default_interaction_type=ExplorationType.DETERMINISTIC,
    )
    value = ValueOperator(_mlp((*sizes, 1), act, 1.0), in_keys=["observation"])
    return actor, value


# --- evaluation -----------------------------------------------------------------------------


def paired_metrics(policy_res, pd_res) -> dict[str, float]:
    """Mean RMSE and improvement vs PD on matched episodes (paper: 1 - mean RL / mean PD)."""
    out = {}
    for name in ("rmse_xy", "rmse_z", "rmse"):
        rl, pd = getattr(policy_res, name).double(), getattr(pd_res, name).double()
        out[f"{name}"] = float(rl.mean())
        out[f"pd_{name}"] = float(pd.mean())
        out[f"improvement_{name}_pct"] = improvement(pd, rl)
    out["improvement_vs_pd"] = out["improvement_rmse_pct"]
    wins, pairs = win_rate(pd_res.rmse, policy_res.rmse)
    out["win_rate"] = wins / pairs
    out["crashed"] = int(policy_res.crashed.sum())
    out["episodes"] = int(policy_res.rmse.numel())
    return out


def evaluate(policy, env: TransformedEnv, scenarios: TensorDictBase, pd_results=None, progress: bool = False):
    """Deterministic flights of ``policy`` on ``scenarios`` in ``env`` (normalisation frozen),
    paired with PD flights on the same scenarios (flown here unless ``pd_results`` is given).
    Returns ``(metrics, policy_results, pd_results)``."""
    vn = vecnorm(env)
    was_frozen = vn.frozen
    vn.freeze()
    try:
        if pd_results is None:
            pd_results = fly(env, scenarios, None, log_keys=("step",), progress=progress)
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            res = fly(env, scenarios, policy, log_keys=("step",), progress=progress)
    finally:
        vn.frozen = was_frozen
    return paired_metrics(res, pd_results), res, pd_results


# --- checkpoints ------------------------------------------------------------------------------


def spec_to_dict(spec: RLEnvSpec) -> dict:
    d = {}
    for f in fields(spec):
        v = getattr(spec, f.name)
        d[f.name] = config_to_dict(v) if f.name in ("config", "ranges") and v is not None else v
    d["env_config"] = config_to_dict(spec.env_config)
    return d


def load_policy(path: str | Path, device="cpu") -> tuple[ProbabilisticActor, dict]:
    """A saved policy (``policy.pt`` or a training checkpoint): ``(actor, payload)``.

    ``payload["vecnorm"]`` is the frozen normalisation to pass to ``make_env(...,
    vecnorm_state=...)``; ``payload["ppo_config"]`` / ``payload["env_spec"]`` describe the run."""
    payload = load_checkpoint(path, "policy", device)
    cfg = payload["ppo_config"]
    cfg = PPOConfig(**{**cfg, "hidden": tuple(cfg["hidden"])})
    actor, _ = build_actor_critic(cfg)
    actor.load_state_dict(payload["policy"])
    return actor.to(device).eval(), payload


# --- the trainer ------------------------------------------------------------------------------


@dataclass
class TrainResult:
    out_dir: Path
    frames: int
    iterations: int
    history: list[dict] = field(default_factory=list)  # per-iteration training metrics
    evals: list[dict] = field(default_factory=list)
    wall_time_s: float = 0.0


class PPOTrainer:
    """Collect -> GAE -> 10 epochs of minibatch ClipPPO updates, with periodic deterministic
    evaluation against PD, CSV (or TensorBoard) logs, checkpoints and resume.

    Output directory::

        OUT/config.json                 the run's PPO config and env spec
        OUT/logs/<exp>/scalars/*.csv    TorchRL CSVLogger (TensorBoard with logger="tensorboard")
        OUT/checkpoints/latest.pt       policy, value, optimiser, VecNorm stats, RNG, progress
        OUT/checkpoints/latest.json     its manifest
        OUT/policy.pt, OUT/policy.json  the final policy + frozen normalisation + manifest
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
    ):
        self.cfg = cfg.validate()
        if env_spec.num_envs != cfg.num_envs:
            env_spec = replace(env_spec, num_envs=cfg.num_envs)
        self.spec = env_spec
        self.out_dir = Path(out_dir)
        self.eval_scenarios = eval_scenarios
        self.curriculum = curriculum
        self.logger_kind = logger
        self.progress = progress
        self.command = command if command is not None else command_line(sys.argv)
        self.factory = EnvFactory(env_spec, bundle=estimator_bundle)
        self.on_iteration = on_iteration

    # --- pieces -------------------------------------------------------------------------------

    def _episode_steps_hint(self) -> int:
        """Mean episode length (env steps) of the training trajectories: the range of the
        first-episode de-synchronisation."""
        from ..envs.simulator import trajectory_library
        from ..envs.trajectories import TRAJECTORY_IDS
        from .envs import DEFAULT_RANGES, DEFAULT_TRAJECTORIES

        s = self.spec
        traj = s.trajectories or DEFAULT_TRAJECTORIES[s.regime]
        ranges = s.ranges or DEFAULT_RANGES[s.regime]
        alt = 0.5 * sum(ranges.altitude_m) if ranges.altitude_m is not None else ranges.top_altitude_m
        ids = torch.tensor([TRAJECTORY_IDS[t] for t in traj])
        start, end = trajectory_library(s.env_config, "cpu").schedule(ids, torch.full((len(traj),), float(alt)))
        steps = end - start if s.start == "pattern" else end
        return max(1, int(steps.float().mean()) // s.env_config.timing.hold_control_steps)

    def _make_logger(self):
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
        return CSVLogger(exp_name="ppo", log_dir=log_dir)

    def _manifest(self, metrics: dict, frames: int, iteration: int, wall: float) -> dict:
        est = self.factory.bundle
        return {
            "command": self.command,
            "git_commit": git_commit(),
            "ppo_config": asdict(self.cfg),
            "env_spec": spec_to_dict(self.spec),
            "curriculum": asdict(self.curriculum) if self.curriculum else None,
            "estimator": {"path": self.spec.estimator_path, "untrained": self.spec.untrained_estimator,
                          "manifest": getattr(est, "manifest", None)},
            "observation_channels": list(OBSERVATION_CHANNELS),
            "frames": frames,
            "iterations": iteration,
            "wall_time_s": round(wall, 1),
            "torch_threads": torch.get_num_threads(),
            "metrics": metrics,
        }

    # --- main loop -----------------------------------------------------------------------------

    def train(self, resume: bool = False) -> TrainResult:
        from torchrl.collectors import Collector
        from tqdm.auto import tqdm

        cfg = self.cfg
        if cfg.threads:
            torch.set_num_threads(cfg.threads)
        ckpt_dir = self.out_dir / "checkpoints"
        latest = ckpt_dir / "latest.pt"
        if latest.exists() and not resume:
            raise FileExistsError(f"{latest} exists: pass --resume to continue that run, or choose another --out")
        if resume and not latest.exists():
            # resumable stages (reproduce.py) always pass --resume: nothing to resume is a fresh start
            print(f"--resume: no checkpoint at {latest}; starting a new run", flush=True)
            resume = False
        ckpt_dir.mkdir(parents=True, exist_ok=True)
        torch.manual_seed(cfg.seed)

        actor, value = build_actor_critic(cfg)
        actor, value = actor.to(self.spec.device), value.to(self.spec.device)
        loss = ClipPPOLoss(
            actor, value,
            clip_epsilon=cfg.clip_epsilon, entropy_coeff=cfg.entropy_coeff, critic_coeff=cfg.critic_coeff,
            loss_critic_type=cfg.loss_critic_type, normalize_advantage=cfg.normalize_advantage,
        )  # fmt: skip
        gae = GAE(gamma=cfg.gamma, lmbda=cfg.lmbda, value_network=value, average_gae=False)
        params = list(loss.parameters())
        optim = torch.optim.Adam(params, lr=cfg.lr, eps=1e-5)  # SB3's Adam eps

        state = {"frames": 0, "iteration": 0, "stage": 0, "pd_eval": None, "wall": 0.0, "evals": [], "last_eval_frames": 0,
                 "last_ckpt_frames": 0}
        ck = None
        if resume:
            ck = torch.load(latest, weights_only=True)
            actor.load_state_dict(ck["policy"])
            value.load_state_dict(ck["value"])
            optim.load_state_dict(ck["optimizer"])
            state.update(ck["progress"])
            torch.random.set_rng_state(ck["rng"])
        else:
            write_json(self.out_dir / "config.json", {"ppo_config": asdict(cfg), "env_spec": spec_to_dict(self.spec),
                                                      "curriculum": asdict(self.curriculum) if self.curriculum else None,
                                                      "command": self.command})

        # the training env: a fresh seed per (resumed) segment so episodes do not repeat
        seed = self.spec.seed + 7919 * state["iteration"]
        desync = self._episode_steps_hint() if cfg.desync else 0
        env = self.factory(seed=seed, desync_steps=desync)
        estimator = self.factory.bundle
        if estimator is not None:
            est_params = {id(p) for p in estimator.model.parameters()}
            if any(id(p) in est_params for p in params):
                raise RuntimeError("estimator parameters found among the optimised parameters")
        if ck is not None:
            load_vecnorm_state(env, ck["vecnorm"])
        if self.curriculum is not None:
            self._apply_stage(env, state["stage"], truncate=False)

        eval_env = None
        if self.eval_scenarios is not None:
            n_eval = self.eval_scenarios.batch_size[0]
            eval_env = self.factory(num_envs=n_eval, seed=self.spec.seed + 1, desync_steps=0)

        logger = self._make_logger()
        remaining = cfg.iterations * cfg.frames_per_batch - state["frames"]
        result = TrainResult(self.out_dir, state["frames"], state["iteration"], evals=list(state["evals"]))
        wall0 = time.perf_counter() - state["wall"]
        if remaining <= 0:
            return self._finish(actor, value, env, state, result, wall0, logger)
        collector = Collector(env, actor, frames_per_batch=cfg.frames_per_batch, total_frames=remaining,
                              exploration_type=ExplorationType.RANDOM, auto_register_policy_transforms=False)
        bar = tqdm(total=cfg.iterations * cfg.frames_per_batch, initial=state["frames"], unit="frame",
                   unit_scale=True, disable=not self.progress, desc="ppo")
        gen = torch.Generator().manual_seed(cfg.seed * 1000 + state["iteration"])
        keys = ("observation", "action", "action_log_prob", ("next", "observation"), ("next", "reward"),
                ("next", "done"), ("next", "terminated"), ("next", "truncated"))
        t_collect0 = time.perf_counter()
        try:
            for data in collector:
                t_collect = time.perf_counter() - t_collect0
                t0 = time.perf_counter()
                stats = self._episode_stats(data)
                batch = data.select(*keys)
                with torch.no_grad():
                    gae(batch)  # [N, T], time last, before flattening
                flat = batch.reshape(-1)
                n = flat.batch_size[0]
                acc: dict[str, torch.Tensor] = {}  # summed on the device: one sync per iteration
                nb = 0
                for _ in range(cfg.epochs):
                    perm = torch.randperm(n, generator=gen)
                    for idx in perm.split(cfg.minibatch):
                        out = loss(flat[idx])
                        total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
                        optim.zero_grad(set_to_none=True)
                        total.backward()
                        gn = torch.nn.utils.clip_grad_norm_(params, cfg.max_grad_norm)
                        optim.step()
                        for k in ("loss_objective", "loss_critic", "loss_entropy", "entropy", "clip_fraction",
                                  "kl_approx", "explained_variance"):
                            if k in out.keys():
                                acc[k] = acc.get(k, 0.0) + out[k].detach().mean()
                        acc["grad_norm"] = acc.get("grad_norm", 0.0) + gn.detach()
                        nb += 1
                t_update = time.perf_counter() - t0
                state["iteration"] += 1
                state["frames"] += data.numel()
                metrics = {k: float(v) / nb for k, v in acc.items()}
                metrics.update(stats)
                metrics.update(
                    frames=state["frames"],
                    collect_s=t_collect,
                    update_s=t_update,
                    fps=data.numel() / max(t_collect, 1e-9),
                    action_scale=float(actor.module[0].module[-1].state_independent_scale.detach().exp().mean()),
                )
                if self.curriculum is not None:
                    metrics["curriculum_stage"] = state["stage"]
                    new_stage = self.curriculum.stage_at(state["frames"], cfg.total_frames)
                    if new_stage != state["stage"]:
                        state["stage"] = new_stage
                        self._apply_stage(env, new_stage, truncate=True)
                try:
                    metrics["estimator_s"] = wind_estimate(env).estimator_seconds
                except KeyError:
                    pass
                state["wall"] = time.perf_counter() - wall0
                metrics["wall_s"] = state["wall"]
                for k, v in metrics.items():
                    logger.log_scalar(f"train/{k}", float(v), step=state["frames"])
                result.history.append(metrics)
                bar.update(data.numel())
                bar.set_postfix(r=f"{metrics['reward_mean']:.3f}", ret=f"{metrics.get('episode_return', float('nan')):.0f}")
                if self.on_iteration is not None:
                    self.on_iteration(metrics)

                last = state["frames"] >= cfg.iterations * cfg.frames_per_batch
                if eval_env is not None and (last or (cfg.eval_every_frames and
                                                      state["frames"] - state["last_eval_frames"] >= cfg.eval_every_frames)):
                    self._evaluate(actor, env, eval_env, state, logger, result)
                if last or state["frames"] - state["last_ckpt_frames"] >= cfg.checkpoint_every_frames:
                    state["last_ckpt_frames"] = state["frames"]
                    self._checkpoint(actor, value, optim, env, state, wall0)
                t_collect0 = time.perf_counter()
        finally:
            bar.close()
            collector.shutdown()
        return self._finish(actor, value, env, state, result, wall0, logger)

    def _apply_stage(self, env: TransformedEnv, stage: int, truncate: bool) -> None:
        base = env.base_env
        base.scenario_sampler = replace(base.scenario_sampler, trajectories=tuple(self.curriculum.stages[stage]))
        if truncate:
            episode_control(env).request_truncation()

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

    def _evaluate(self, actor, env, eval_env, state, logger, result) -> None:
        load_vecnorm_state(eval_env, vecnorm_state_dict(env))
        vecnorm(eval_env).freeze()
        t0 = time.perf_counter()
        pd = state["pd_eval"]
        if pd is not None:
            from ..envs.runner import FlightResults

            pd = FlightResults(index=pd["index"], rmse_xy=pd["rmse_xy"], rmse_z=pd["rmse_z"], crashed=pd["crashed"],
                               log=TensorDict({}, batch_size=[pd["index"].numel(), 0]))
        metrics, _, pd_res = evaluate(actor, eval_env, self.eval_scenarios, pd_results=pd)
        if state["pd_eval"] is None:
            state["pd_eval"] = {"index": pd_res.index, "rmse_xy": pd_res.rmse_xy, "rmse_z": pd_res.rmse_z,
                                "crashed": pd_res.crashed}
        metrics["eval_s"] = time.perf_counter() - t0
        metrics["frames"] = state["frames"]
        state["last_eval_frames"] = state["frames"]
        state["evals"] = list(state["evals"]) + [metrics]
        for k, v in metrics.items():
            logger.log_scalar(f"eval/{k}", float(v), step=state["frames"])
        result.evals.append(metrics)
        if self.progress:
            print(f"[eval @ {state['frames']} frames] rmse {metrics['rmse']:.3f} m vs PD {metrics['pd_rmse']:.3f} m "
                  f"(RMSE reduction {metrics['improvement_vs_pd']:+.1f} %, positive = better), win rate {metrics['win_rate']:.2f}, "
                  f"crashed {metrics['crashed']}, {metrics['eval_s']:.0f} s", flush=True)

    def _payload(self, actor, env) -> dict:
        return {
            "format": CHECKPOINT_FORMAT,
            "kind": "policy",  # validation.load_checkpoint tells a policy from an estimator by it
            "policy": actor.state_dict(),
            "vecnorm": vecnorm_state_dict(env),
            "ppo_config": asdict(self.cfg),
            "env_spec": spec_to_dict(self.spec),
            "observation_channels": list(OBSERVATION_CHANNELS),
        }

    def _checkpoint(self, actor, value, optim, env, state, wall0) -> None:
        state["wall"] = time.perf_counter() - wall0
        payload = self._payload(actor, env)
        payload.update(value=value.state_dict(), optimizer=optim.state_dict(), rng=torch.random.get_rng_state(),
                       progress=dict(state))
        ckpt_dir = self.out_dir / "checkpoints"
        save_atomic(payload, ckpt_dir / "latest.pt")
        last_eval = state["evals"][-1] if state["evals"] else {}
        write_json(ckpt_dir / "latest.json", self._manifest(last_eval, state["frames"], state["iteration"], state["wall"]))

    def _finish(self, actor, value, env, state, result, wall0, logger) -> TrainResult:
        state["wall"] = time.perf_counter() - wall0
        payload = self._payload(actor, env)
        payload["value"] = value.state_dict()
        save_atomic(payload, self.out_dir / "policy.pt")
        last_eval = state["evals"][-1] if state["evals"] else {}
        manifest = self._manifest(last_eval, state["frames"], state["iteration"], state["wall"])
        manifest["evals"] = state["evals"]
        write_json(self.out_dir / "policy.json", manifest)
        result.frames, result.iterations, result.wall_time_s = state["frames"], state["iteration"], state["wall"]
        result.evals = list(state["evals"])
        return result


def default_eval_scenarios(regime: str, episodes: int = 5) -> TensorDictBase:
    """A small fixed evaluation set: ``episodes`` rows of the regime's paper sweep, one per
    trajectory first, spread over the wind levels (held-out design seed, like the sweep)."""
    from ..regimes import HORIZONTAL_SWEEP, VERTICAL_SWEEP

    sweep = HORIZONTAL_SWEEP if regime == "horizontal" else VERTICAL_SWEEP
    sc = sweep.scenarios()
    n = sc.batch_size[0]
    t = len(sweep.trajectories)
    cases = n // t
    # case-major, trajectory-minor: pick case c_i (spread over the grid) for trajectory i % t
    rows = []
    for i in range(episodes):
        case = (i * (cases // max(episodes, 1)) + 7 * i) % cases
        rows.append(case * t + (i % t))
    return sc[torch.tensor(rows)].exclude("case_id", "seed_index")
