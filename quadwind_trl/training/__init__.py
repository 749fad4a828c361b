"""Training loops that are not PPO: the wind estimator (:mod:`.estimator`)."""
from .estimator import (
    EstimatorData,
    TrainConfig,
    TrainResult,
    evaluate_table,
    full_config,
    load_estimator_data,
    quick_config,
    resume_path,
    train_estimator,
)

__all__ = [
    "EstimatorData",
    "TrainConfig",
    "TrainResult",
    "evaluate_table",
    "full_config",
    "load_estimator_data",
    "quick_config",
    "resume_path",
    "train_estimator",
]
