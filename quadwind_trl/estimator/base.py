"""The interface every wind estimator implements, and what the env's ``WindEstimate`` relies on.

A wind estimator reads a window of raw (unstandardised) 10 Hz features of one feature schema and
returns the mean horizontal wind as (north, east) in m/s. The attention-GRU checkpoint
(:class:`~quadwind_trl.estimator.checkpoint.EstimatorBundle`) is one; a model-based estimator is
one more class with these five members, with no change to the transforms::

    class MyEstimator:
        schema = "horizontal"                     # which FeatureExtractor builds its input
        channels = make_extractor("horizontal").channels
        window = 60                               # samples per window (10 Hz)

        def predict(self, windows):               # [B, window, len(channels)] -> [B, 2]
            ...
        def to(self, device):
            return self
"""
from __future__ import annotations

from typing import Protocol, runtime_checkable

import torch
from torch import Tensor


@runtime_checkable
class WindEstimator(Protocol):
    """A frozen estimator of the mean wind from a window of estimator features."""

    #: feature schema (``"horizontal"`` / ``"vertical"``): which feature extractor builds the input
    schema: str
    #: the feature channel names, in input order (must equal the extractor's)
    channels: tuple[str, ...]
    #: number of 10 Hz samples in one input window (oldest first)
    window: int

    def predict(self, windows: Tensor) -> Tensor:
        """Raw feature windows ``[B, window, C]`` -> mean wind ``[B, 2]`` (north, east), m/s."""
        ...

    def to(self, device: torch.device | str) -> "WindEstimator":
        """Move to ``device`` (returns the estimator)."""
        ...
