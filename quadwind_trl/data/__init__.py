"""Flight-log datasets, windows, wind-case splits and the balanced sampler (the estimator
features themselves are :mod:`quadwind_trl.estimator.features`).

* :mod:`.generate`: PD-flown LHS datasets stored as memory-mapped tensordicts;
* :mod:`.windows`: climb-aware crop, 70/15/15 split by wind case, window tables, sampler, stats.

See ``docs/features.md``.
"""
from .generate import GenerationSpec, generate_dataset, is_complete, load_dataset, quick_spec
from .windows import (
    CaseBalancedSampler,
    Standardizer,
    WindowDataset,
    WindowedData,
    compute_features,
    crop_start,
    prepare_windows,
    split_cases,
    window_table,
)

__all__ = [
    "GenerationSpec",
    "generate_dataset",
    "is_complete",
    "load_dataset",
    "quick_spec",
    "CaseBalancedSampler",
    "Standardizer",
    "WindowDataset",
    "WindowedData",
    "compute_features",
    "crop_start",
    "prepare_windows",
    "split_cases",
    "window_table",
]
