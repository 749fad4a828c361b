"""Which rows a TorchRL reset call restarts (shared by the stateful transforms)."""
from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torch import Tensor


def reset_mask(tensordict: TensorDictBase | None, n: int, device: torch.device | str) -> Tensor:
    """bool ``[n]``: the rows a reset call restarts (all rows for a full reset)."""
    mask = tensordict.get("_reset", None) if tensordict is not None else None
    if mask is None:
        return torch.ones(n, dtype=torch.bool, device=device)
    return mask.reshape(n).to(device)
