"""Group per-episode values by a label (wind level, trajectory, ...) into summary rows."""
from __future__ import annotations

from dataclasses import asdict, dataclass

from torch import Tensor


@dataclass(frozen=True)
class GroupStats:
    n: int
    mean: float
    std: float
    median: float
    max: float

    def as_dict(self) -> dict:
        return asdict(self)


def summarize(values: Tensor) -> GroupStats:
    v = values.double()
    return GroupStats(
        n=v.numel(),
        mean=v.mean().item(),
        std=v.std().item() if v.numel() > 1 else 0.0,
        median=v.median().item(),
        max=v.max().item(),
    )


def group_stats(values: Tensor, labels: Tensor) -> dict[float | int, GroupStats]:
    """Summary statistics of ``values`` for each distinct ``label`` (sorted)."""
    out = {}
    for label in labels.unique(sorted=True).tolist():
        out[label] = summarize(values[labels == label])
    return out
