"""Wind-aware residual PPO on TorchRL. See docs/rl.md.

* ``envs``: the env factory (``make_env``, ``build_env``, ``RLEnvSpec``, ``EnvFactory``);
* ``config``: ``PPOConfig`` (paper settings beside ours) and the trajectory ``Curriculum``;
* ``policy``: the actor-critic networks and the policy file (``load_policy``);
* ``update``: the PPO update (GAE + minibatch ClipPPO epochs);
* ``paired``: controllers flown on identical replayed episodes, improvement and win rate vs PD;
* ``trainer``: ``PPOTrainer``, collect -> update -> evaluate -> checkpoint;
* ``cli``: what the two PPO recipes share;
* ``screening``: the learning levers screened on validation flights (``recipes/screen_levers.py``).
"""
from .config import Curriculum, PPOConfig, vertical_curriculum
from ..regimes import regime_config
from .envs import EnvFactory, RLEnvSpec, build_env, make_env
from .paired import fly_paired, paired_metrics
from .policy import build_actor_critic, load_policy, network_dims
from .trainer import PPOResult, PPOTrainer

__all__ = [
    "EnvFactory",
    "RLEnvSpec",
    "build_env",
    "make_env",
    "regime_config",
    "Curriculum",
    "PPOConfig",
    "PPOResult",
    "PPOTrainer",
    "build_actor_critic",
    "fly_paired",
    "load_policy",
    "network_dims",
    "paired_metrics",
    "vertical_curriculum",
]
