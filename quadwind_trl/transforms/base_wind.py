"""The wind estimate's way into the base controller: ``BaseWindInput``.

A wind feed-forward base law (``ControllerConfig.disturbance="wind_model"``) runs inside the
simulator at the control rate, while the estimate is made in the transform stack (``WindEstimate``,
at the 10 Hz log ticks). The estimate therefore enters the base env the way the action does: as
an input of its step. ``BaseWindInput`` keeps the last wind it saw on the way out (after a reset
or a step) and writes it as :data:`~quadwind_trl.keys.BASE_WIND_KEY` on the way in (TorchRL's
inverse path), so the simulator flies each step on the estimate held since the last update. It
keeps its own copy rather than reading the step's input tensordict because collection workers
and ``step_mdp`` carry only the declared inputs (the action) into a step.

``source``: ``"estimate"`` reads ``wind_hat`` (``WindEstimate``'s filtered estimate; place this
transform after it), ``"truth"`` the true turbulence-free mean wind at the vehicle (the oracle),
``"zero"`` gives zero (the blind twin: the same law with no wind knowledge).
"""
from __future__ import annotations

from typing import Literal

import torch
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.data import Composite
from torchrl.envs import Transform

from ..keys import BASE_WIND_KEY, MEAN_WIND_KEY, WIND_KEY

BASE_WIND_SOURCES = ("estimate", "truth", "zero")


class BaseWindInput(Transform):
    """Gives the base env's step its ``base_wind_ne`` [2] (north, east, m/s) from ``source``."""

    def __init__(self, source: Literal["estimate", "truth", "zero"] = "estimate"):
        if source not in BASE_WIND_SOURCES:
            raise ValueError(f"BaseWindInput.source={source!r}; allowed: {BASE_WIND_SOURCES}")
        super().__init__(in_keys=[], out_keys=[], in_keys_inv=[], out_keys_inv=[BASE_WIND_KEY])
        self.source = source
        self.held: Tensor | None = None  # [N, 2] the wind the next step flies on

    def _read(self, td: TensorDictBase) -> Tensor:
        if self.source == "estimate":
            return td.get(WIND_KEY).clone()
        mean = td.get(MEAN_WIND_KEY)
        wind = torch.stack((mean[..., 1], mean[..., 0]), -1)  # ENU -> (north, east)
        return wind if self.source == "truth" else torch.zeros_like(wind)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        # every row: a row that did not restart reports its held estimate again
        self.held = self._read(tensordict_reset)
        return tensordict_reset

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        self.held = self._read(next_tensordict)
        return next_tensordict

    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase:
        if self.held is None:
            raise RuntimeError("BaseWindInput: step before reset (no wind estimate yet)")
        tensordict.set(BASE_WIND_KEY, self.held)
        return tensordict

    def transform_input_spec(self, input_spec: Composite) -> Composite:
        # the outer env's step no longer needs the entry: this transform provides it
        state = input_spec["full_state_spec"]
        if BASE_WIND_KEY in state.keys():
            del state[BASE_WIND_KEY]
        return input_spec

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        return tensordict  # stored rows carry their own inputs: nothing to give
