"""TorchRL transforms of the wind-aware pipeline (each usable alone in user code).

* :class:`WindEstimate`: any frozen estimator (``quadwind_trl.estimator.WindEstimator``) on its
  per-sub-env 10 Hz feature ring + spike-gated EMA -> ``wind_hat`` (north, east);
  ``source="truth"`` writes the true mean wind instead (oracle).
* :class:`BaseWindInput`: the wind estimate (or the true mean wind, or zero) as the step input
  of a wind feed-forward base controller.
* :class:`ZeroInputs`: named policy inputs forced to 0 (the ablations: the two wind inputs, or
  others a policy trains without).
* :class:`PolicyObservation`: the paper's 23-dim ``observation`` (layout and keys:
  :mod:`quadwind_trl.keys`, wind at ``WIND_INDICES``, looked up by channel name), optionally
  followed by named channels of the base controller's state and of the reference ahead.
* :class:`ReferenceAhead`: where the reference will be 0.5, 1 and 2 s from now, from the vehicle
  (``ref_ahead``), for a policy that plans.
* :class:`PrivilegedObservation`: simulator truth (true mean wind, turbulence, true errors) for an
  asymmetric critic at training time only (``privileged``).
* :class:`ObservationStack`: the last K observations side by side (a policy with memory).
* :class:`EpisodeControl`: de-synchronised first episodes, truncation on request (training).
* :class:`RunningObsNorm`: ``VecNormV2`` (running mean/variance) without its NaN on constant
  channels.

Composing them (``quadwind_trl.rl.envs.make_env`` builds the full training stack)::

    from torchrl.envs import Compose, TransformedEnv
    from quadwind_trl.envs import QuadWindEnv
    from quadwind_trl.estimator import load_estimator
    from quadwind_trl.keys import WIND_CHANNELS
    from quadwind_trl.transforms import PolicyObservation, RunningObsNorm, WindEstimate, ZeroInputs

    env = TransformedEnv(QuadWindEnv(batch_size=[64]), Compose(
        WindEstimate(load_estimator("horizontal")),         # -> wind_hat (north, east)
        PolicyObservation(),                                 # -> observation [23]
        RunningObsNorm(in_keys=["observation"], decay=1.0, reduce_batch_dims=True),
        ZeroInputs(WIND_CHANNELS),                           # the ablation: wind channels = 0
    ))
"""
from .base_wind import BaseWindInput
from .episode import EpisodeControl
from .memory import ObservationStack
from .normalization import RunningObsNorm
from .observation import PolicyObservation, PrivilegedObservation, ReferenceAhead, ZeroInputs
from .wind import WindEstimate

__all__ = [
    "BaseWindInput",
    "EpisodeControl",
    "ObservationStack",
    "PolicyObservation",
    "PrivilegedObservation",
    "ReferenceAhead",
    "RunningObsNorm",
    "WindEstimate",
    "ZeroInputs",
]
