"""The TensorDicts the simulator builds at every step, made without the constructor's checks."""
from __future__ import annotations

import torch
from tensordict import TensorDict
from tensordict.base import NO_DEFAULT
from torch import Tensor


def unchecked(batch_size: torch.Size, entries: dict) -> TensorDict:
    """A TensorDict of the simulator's own ``entries`` (tensors and TensorDicts of batch
    ``batch_size``, on one device), built without the constructor's per-entry checks: a step
    builds a dozen, and at small batches the checks cost more than the arithmetic (80 us against
    6 us for six entries; compiled, ``_new_unsafe`` is the constructor)."""
    return TensorDict._new_unsafe(entries, batch_size=batch_size)


def entry(td: TensorDict, *path: str):
    """``td[path]``, the entry at the nested key ``path`` of a TensorDict the simulator built,
    read straight from each level's dict: ``__getitem__``'s dispatch on the key's type and the
    tracing state costs a dozen times the lookup, and a step reads a hundred entries."""
    for key in path:
        td = td._get_str(key, NO_DEFAULT)
    return td


def select_rows(keep: Tensor, new: TensorDict, old: TensorDict) -> TensorDict:
    """``new``'s rows where ``keep`` (``[N]`` bool), else ``old``'s, for every leaf of ``new`` (a
    leaf ``old`` lacks is a ``KeyError``): ``new.where(keep, old)``, the same bits, without its
    per-leaf key dispatch and mask expansion, which cost the eager step about 1 ms per call at
    small batches (33 leaves: a tenth of a decision's ten control steps)."""
    masks: dict[int, Tensor] = {}  # the mask shaped for leaves of each rank, made once per rank

    def select(new_td: TensorDict, old_td: TensorDict) -> TensorDict:
        entries = {}
        for key, value in new_td.items():
            other = old_td._get_str(key, NO_DEFAULT)
            if isinstance(value, TensorDict):
                entries[key] = select(value, other)
                continue
            mask = masks.get(value.dim())
            if mask is None:
                mask = masks[value.dim()] = keep.reshape(keep.shape + (1,) * (value.dim() - 1))
            entries[key] = torch.where(mask, value, other)
        return unchecked(new_td.batch_size, entries)

    return select(new, old)
