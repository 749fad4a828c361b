"""TorchRL transforms of the wind-aware pipeline (each usable alone in user code).

* :class:`FeatureHistory`: per-sub-env causal 10 Hz estimator features and their 60-sample ring.
* :class:`WindEstimate`: the frozen estimator + spike-gated EMA -> ``wind_hat`` (north, east);
  ``source="truth"`` writes the true mean wind instead (oracle).
* :class:`WindZero`: the perception ablation (the policy's two wind inputs forced to 0).
* :class:`PolicyObservation`: the paper's 23-dim ``observation`` (layout: ``OBSERVATION_CHANNELS``,
  wind at ``WIND_INDICES`` = (13, 14)).
* :class:`EpisodeControl`: de-synchronised first episodes, truncation on request (training).
* :class:`RunningObsNorm`: ``VecNormV2`` (running mean/variance) without its NaN on constant
  channels.

Composing them (``quadwind_trl.rl.envs.make_env`` builds the full training stack)::

    from torchrl.envs import Compose, TransformedEnv
    from quadwind_trl.envs import QuadWindEnv
    from quadwind_trl.modules.wind_estimator import pretrained_estimator
    from quadwind_trl.transforms import PolicyObservation, RunningObsNorm, WindEstimate, WindZero

    env = TransformedEnv(QuadWindEnv(batch_size=[64]), Compose(
        WindEstimate(pretrained_estimator("horizontal")),   # -> wind_hat (north, east)
        PolicyObservation(),                                 # -> observation [23]
        RunningObsNorm(in_keys=["observation"], decay=1.0, reduce_batch_dims=True),
        WindZero(),                                          # the ablation: observation[13:15] = 0
    ))
"""
from .episode import EpisodeControl
from .history import WINDOW, FeatureHistory, FeatureRing
from .normalization import RunningObsNorm
from .observation import OBSERVATION_CHANNELS, OBSERVATION_DIM, WIND_INDICES, PolicyObservation
from .wind import WIND_KEY, WindEstimate, WindZero

__all__ = [
    "EpisodeControl",
    "FeatureHistory",
    "FeatureRing",
    "WINDOW",
    "OBSERVATION_CHANNELS",
    "OBSERVATION_DIM",
    "WIND_INDICES",
    "PolicyObservation",
    "RunningObsNorm",
    "WIND_KEY",
    "WindEstimate",
    "WindZero",
]
