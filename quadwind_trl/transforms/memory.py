"""A policy with memory: the last K observations side by side (:class:`ObservationStack`).

TorchRL's ``CatFrames`` does the same on the env path, but its partial reset indexes the buffer
with the ``"_reset"`` mask (``buffer[_reset] = ...``, after ``_reset.all()``): a host sync at every
reset of a batched env. Here a reset is one ``torch.where`` over the batch, and a step one
shift: nothing waits on the device.
"""
from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded
from torchrl.envs import Transform

from ..keys import OBSERVATION_KEY


class ObservationStack(Transform):
    """``in_key`` (``[*batch, D]``) replaced by its last ``frames`` values, oldest first, newest
    last: ``[*batch, frames * D]``.

    One frame per env step (a decision: the env's ``hold`` control steps happen inside it). A
    reset fills the stack of the rows that restart (the ``"_reset"`` mask; all rows without one)
    with their first observation repeated, and leaves the other rows' stacks as they are.
    ``frames=1`` is the observation unchanged.
    """

    def __init__(self, frames: int, *, in_key: str = OBSERVATION_KEY):
        if not isinstance(frames, int) or isinstance(frames, bool) or frames < 1:
            raise ValueError(f"ObservationStack(frames={frames!r}); allowed: a whole number >= 1 (1: no memory)")
        super().__init__(in_keys=[in_key], out_keys=[in_key])
        self.frames = frames
        self.register_buffer("_stack", None, persistent=False)  # [*batch, frames, D]

    def _push(self, obs: torch.Tensor, reset: torch.Tensor | None) -> torch.Tensor:
        """The stack after ``obs``: shifted by one frame, or (rows of ``reset``, or all rows when
        ``reset`` is None or the stack is new) ``obs`` repeated."""
        filled = obs.unsqueeze(-2).expand(*obs.shape[:-1], self.frames, obs.shape[-1])
        stack = self._stack
        if stack is None or stack.shape != filled.shape or stack.device != obs.device:
            stack = filled.clone()
        elif reset is None:
            stack = torch.cat((stack[..., 1:, :], obs.unsqueeze(-2)), -2)
        else:
            stack = torch.where(reset.reshape(*obs.shape[:-1], 1, 1), filled, stack)
        self._stack = stack
        return stack.flatten(-2)

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        key = self.in_keys[0]
        next_tensordict.set(key, self._push(next_tensordict.get(key), None))
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        key = self.in_keys[0]
        obs = tensordict_reset.get(key)
        mask = None if tensordict is None else tensordict.get("_reset", None)
        if mask is None:  # a full reset
            self._stack = None
            mask = torch.ones(obs.shape[:-1], dtype=torch.bool, device=obs.device)
        tensordict_reset.set(key, self._push(obs, mask))
        return tensordict_reset

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        key = self.in_keys[0]
        spec = observation_spec[key]
        observation_spec[key] = Unbounded(shape=(*spec.shape[:-1], spec.shape[-1] * self.frames), device=spec.device,
                                          dtype=spec.dtype)
        return observation_spec
