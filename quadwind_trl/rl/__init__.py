"""Wind-aware residual PPO on TorchRL: the env factory (``envs``), the trainer (``ppo``) and what
the recipes share (``cli``). See docs/rl.md."""
from .envs import EnvFactory, RLEnvSpec, load_estimator, make_env, untrained_estimator
from .ppo import Curriculum, PPOConfig, PPOTrainer, build_actor_critic, evaluate, load_policy, vertical_curriculum

__all__ = [
    "EnvFactory",
    "RLEnvSpec",
    "load_estimator",
    "make_env",
    "untrained_estimator",
    "Curriculum",
    "PPOConfig",
    "PPOTrainer",
    "build_actor_critic",
    "evaluate",
    "load_policy",
    "vertical_curriculum",
]
