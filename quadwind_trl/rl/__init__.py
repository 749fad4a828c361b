"""Wind-aware residual PPO on TorchRL: the env factory (``envs``), the trainer (``ppo``) and what
the recipes share (``cli``). See docs/rl.md."""
from .envs import EnvFactory, RLEnvSpec, build_env, make_env, regime_config
from .ppo import Curriculum, PPOConfig, PPOTrainer, build_actor_critic, evaluate, load_policy, vertical_curriculum

__all__ = [
    "EnvFactory",
    "RLEnvSpec",
    "build_env",
    "make_env",
    "regime_config",
    "Curriculum",
    "PPOConfig",
    "PPOTrainer",
    "build_actor_critic",
    "evaluate",
    "load_policy",
    "vertical_curriculum",
]
