"""Flight-log datasets, estimator features, windows, wind-case splits and the balanced sampler.

* :mod:`.features`: the incremental feature extractor (one code path offline and online);
* :mod:`.generate`: PD-flown LHS datasets stored as memory-mapped tensordicts;
* :mod:`.windows`: climb-aware crop, 70/15/15 split by wind case, window tables, sampler, stats.

See ``docs/features.md``.
"""
from .features import (
    HORIZONTAL_CHANNELS,
    RAW_RECORD_KEYS,
    VERTICAL_CHANNELS,
    FeatureExtractor,
    make_extractor,
)
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
    "HORIZONTAL_CHANNELS",
    "VERTICAL_CHANNELS",
    "RAW_RECORD_KEYS",
    "FeatureExtractor",
    "make_extractor",
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
