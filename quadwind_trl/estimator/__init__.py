"""The wind estimator: everything between the 10 Hz flight record and ``wind_hat``.

* :mod:`.base`: the :class:`WindEstimator` interface (``schema``, ``channels``, ``window``,
  ``predict(windows [B, W, C]) -> [B, 2]`` north/east m/s) that ``WindEstimate`` relies on;
* :mod:`.features`: the incremental feature extractor (one code path offline and online);
* :mod:`.ring`: the per-sub-env online feature ring;
* :mod:`.model`: the attention-GRU network; :mod:`.loss`: its training loss;
* :mod:`.metrics`: the estimation metrics (training validates with them, the evaluation reports them);
* :mod:`.checkpoint`: :class:`EstimatorBundle` (a trained network + standardisation, a
  ``WindEstimator``), the registry of network classes and the loaders of shipped checkpoints;
* :mod:`.ema`: the spike-gated EMA post-filter (``DEFAULT_TAU_S``);
* :mod:`.ukf`: :class:`WindUKF`, a model-based ``WindEstimator`` (an unscented Kalman filter on
  the airframe's drag law, with stated model error, :class:`UKFConfig`);
* :mod:`.training`: the training run (imports the datasets: not re-exported here, so the
  transforms never pull the dataset generator).

See ``docs/estimator.md`` and ``docs/features.md``.
"""
from .base import WindEstimator
from .checkpoint import (
    EstimatorBundle,
    default_estimator_path,
    load_estimator,
    register_model,
    untrained_estimator,
)
from .ema import DEFAULT_TAU_S, EMAConfig, ema_scan
from .features import HORIZONTAL_CHANNELS, RAW_RECORD_KEYS, VERTICAL_CHANNELS, FeatureExtractor, make_extractor
from .loss import EstimatorLoss, EstimatorLossConfig
from .model import AttentionGRUEstimator, EstimatorConfig
from .ring import FeatureRing
from .ukf import UKFConfig, WindUKF

__all__ = [
    "WindEstimator",
    "EstimatorBundle",
    "default_estimator_path",
    "load_estimator",
    "register_model",
    "untrained_estimator",
    "DEFAULT_TAU_S",
    "EMAConfig",
    "ema_scan",
    "HORIZONTAL_CHANNELS",
    "VERTICAL_CHANNELS",
    "RAW_RECORD_KEYS",
    "FeatureExtractor",
    "make_extractor",
    "EstimatorLoss",
    "EstimatorLossConfig",
    "AttentionGRUEstimator",
    "EstimatorConfig",
    "FeatureRing",
    "UKFConfig",
    "WindUKF",
]
