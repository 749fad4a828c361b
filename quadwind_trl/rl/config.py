"""The PPO settings (:class:`PPOConfig`) and the trajectory curriculum (:class:`Curriculum`).

Paper settings (Section "Policy, observation, and action"; Stable-Baselines3 there) and ours:

==========================  =====================  =============================================
setting                     paper                  here
==========================  =====================  =============================================
actor / critic              MLP 2 x 256            separate MLPs 2 x 256, Tanh (SB3's default)
action distribution         (SB3: diag. Gaussian,  TanhNormal on [-1, 1]^4 (exact log-probs of the
                            clipped to bounds)     bounded action), state-independent scale
learning rate               3e-4, constant         3e-4 (Adam, eps 1e-5 as SB3) decayed
                                                   linearly to 0 over the run (lr_schedule,
                                                   chosen by experiment: docs/rl.md,
                                                   "Choosing the training recipe")
reward scaling              (not stated)           none; reward_scaling "return_std" divides by
                                                   the running std of the discounted return
                                                   (a recipe candidate, rl/reward_scale.py)
value normalisation         (SB3: none)            none; value_norm=True: the critic learns its
                                                   targets standardised by their running mean
                                                   and std, PopArt-style (rl/value_norm.py)
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
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

from torch import nn

ACTIVATIONS = {"tanh": nn.Tanh, "elu": nn.ELU, "relu": nn.ReLU}
# "constant": the paper's fixed rate; "linear": from ``lr`` at the first update to 0 at the end of
# the planned run (CleanRL's anneal_lr; Huang et al. 2022, "The 37 implementation details of PPO")
LR_SCHEDULES = ("constant", "linear")
# "none": the paper's rewards; "return_std": divided by the running std of the discounted return
# (SB3's VecNormalize(norm_reward=True); rl/reward_scale.py)
REWARD_SCALINGS = ("none", "return_std")
# where the rows are stepped: "local" (this process, or collect_workers processes of this machine)
# or "ray" (num_collectors Ray actors, on any node of a Ray cluster; rl/collection.py)
COLLECTORS = ("local", "ray")


@dataclass(frozen=True)
class PPOConfig:
    total_frames: int = 1_500_000  # decisions at 10 Hz; paper: ~3M env steps at 100 Hz (docs/rl.md)
    num_envs: int = 64
    steps_per_env: int = 256  # frames per batch = num_envs * steps_per_env (paper: 2048 per env)
    epochs: int = 10  # paper
    minibatch: int = 512  # paper
    lr: float = 3e-4  # paper
    lr_schedule: str = "linear"  # one of LR_SCHEDULES; the paper: "constant" (docs/rl.md, "Choosing the training recipe")
    reward_scaling: str = "none"  # paper; one of REWARD_SCALINGS
    # the critic predicts its targets standardised by their running mean / std, rescaled to returns
    # for GAE (PopArt-style, rl/value_norm.py); False: the paper's critic on the return scale
    value_norm: bool = False
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
    threads: int | None = 1  # torch intra-op threads of the run (None: torch's default)
    # threads of the PPO update alone (None: ``threads``): collection and update alternate in one
    # process, so a core that the single-threaded simulator leaves idle can serve the update
    update_threads: int | None = None
    # collection processes (rl.envs.build_env(workers=)): one single-threaded simulator process per
    # core, each stepping num_envs / collect_workers rows; the rows fly the same episodes as with 1
    collect_workers: int = 1
    # "ray": the rows split over num_collectors Ray actors as collect_workers splits them over local
    # processes (the same batches, bit for bit); the policy, the normalisation and the update stay here
    collector: str = "local"  # one of COLLECTORS
    num_collectors: int = 1  # Ray actors of num_envs / num_collectors rows each (collector="ray")
    # the Ray cluster (collector="ray"): "auto" (the one `ray start` joined here, or RAY_ADDRESS),
    # "HOST:PORT" of its head node, or None: a local Ray instance of num_collectors CPUs for the run
    ray_address: str | None = None
    # fly the periodic evaluations in a child process while training goes on (rl.evaluator): the
    # same metrics, off the run's critical path where a core is idle during collection
    background_eval: bool = False

    @property
    def frames_per_batch(self) -> int:
        return self.num_envs * self.steps_per_env

    @property
    def iterations(self) -> int:
        return max(1, math.ceil(self.total_frames / self.frames_per_batch))

    @property
    def planned_frames(self) -> int:
        """Frames of the whole run: whole batches, at least ``total_frames``."""
        return self.iterations * self.frames_per_batch

    def lr_at(self, frames: int) -> float:
        """The learning rate of the update that follows ``frames`` collected frames."""
        if self.lr_schedule == "linear":
            return self.lr * max(0.0, 1.0 - frames / self.planned_frames)
        return self.lr

    def validate(self) -> "PPOConfig":
        for name in ("num_envs", "steps_per_env", "epochs", "minibatch", "total_frames", "collect_workers",
                     "num_collectors") + tuple(
                name for name in ("threads", "update_threads") if getattr(self, name) is not None):
            if getattr(self, name) < 1:
                raise ValueError(f"PPOConfig.{name}={getattr(self, name)} must be >= 1")
        if self.num_envs % self.collect_workers:
            raise ValueError(f"PPOConfig.collect_workers={self.collect_workers} must divide num_envs={self.num_envs}")
        self._validate_collector()
        if self.frames_per_batch % self.minibatch:
            raise ValueError(
                f"PPOConfig: num_envs * steps_per_env = {self.frames_per_batch} must be a multiple of minibatch={self.minibatch}"
            )
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"PPOConfig.activation={self.activation!r}; allowed: {sorted(ACTIVATIONS)}")
        if self.lr_schedule not in LR_SCHEDULES:
            raise ValueError(f"PPOConfig.lr_schedule={self.lr_schedule!r}; allowed: {list(LR_SCHEDULES)}")
        if self.reward_scaling not in REWARD_SCALINGS:
            raise ValueError(f"PPOConfig.reward_scaling={self.reward_scaling!r}; allowed: {list(REWARD_SCALINGS)}")
        if not isinstance(self.value_norm, bool):
            raise ValueError(f"PPOConfig.value_norm={self.value_norm!r}; allowed: True or False")
        if not 0 < self.lr:
            raise ValueError(f"PPOConfig.lr={self.lr} must be > 0")
        if not 0 < self.init_scale < math.inf:
            raise ValueError(f"PPOConfig.init_scale={self.init_scale}; allowed: finite, > 0")
        return self

    def _validate_collector(self) -> None:
        if self.collector not in COLLECTORS:
            raise ValueError(f"PPOConfig.collector={self.collector!r}; allowed: {list(COLLECTORS)}")
        if self.num_envs % self.num_collectors:
            raise ValueError(f"PPOConfig.num_collectors={self.num_collectors} (--num-collectors) must divide "
                             f"num_envs={self.num_envs} (--num-envs)")
        if self.collector == "local":
            if self.num_collectors != 1 or self.ray_address is not None:
                raise ValueError(f"PPOConfig.num_collectors={self.num_collectors}, ray_address={self.ray_address!r}: "
                                 "Ray settings, allowed only with collector='ray' (--collector ray)")
            return
        if self.collect_workers != 1:
            raise ValueError(f"PPOConfig.collect_workers={self.collect_workers}: local collection processes; with "
                             "collector='ray' the rows are split over num_collectors Ray actors (--num-collectors)")
        if self.ray_address not in (None, "auto"):
            from ..ray_cluster import RayUnavailable, parse_address

            try:
                parse_address(self.ray_address)
            except RayUnavailable as err:  # its message names --address and the form expected
                raise ValueError(f"PPOConfig.ray_address: {err}") from None


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
            raise ValueError(f"Curriculum: {len(self.stages)} stages and {len(self.starts)} starts={self.starts}; "
                             "allowed: one start fraction per stage, at least one stage")
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
