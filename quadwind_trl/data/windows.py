"""Training windows over flight features: the climb-aware crop, the split by wind case, the
wind-case-balanced sampler and the standardisation statistics (training split only).

Windows are index-based: a window is a row ``(flight, end)`` of an int64 table and its samples are
``features[flight, end - 59 : end + 1]``, gathered on demand; nothing is copied per window. The
label of a window is the mean wind (north, east) at its last sample (causal estimation).
"""
from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Iterator, Sequence

import torch
from tensordict import TensorDict
from tensordict.memmap import MemoryMappedTensor
from torch import Tensor
from torch.utils.data import Dataset, Sampler

from ..config import TrajectoryConfig
from ..envs.trajectories import fixed_altitude_mask
from ..estimator.features import FeatureExtractor

WINDOW = 60  # paper: 60 samples = 6 s at 10 Hz
STRIDE = {"horizontal": 12, "vertical": 16}  # paper
T_MIN_S = 8.0  # paper: the crop never starts before this
SETTLE_S = 2.0  # ours: settling after the climb's end before the pattern is trusted
SPLIT_FRACTIONS = (0.70, 0.15, 0.15)  # paper: train / val / test, by wind case
SPLIT_SEED = 0
SPLITS = ("train", "val", "test")


def t_safety_s(traj: TrajectoryConfig, settle_s: float = SETTLE_S) -> float:
    """``t_safety`` of the crop: arming time + the climb's end blend + ``settle_s``
    (1 + 3 + 2 = 6 s by default), so ``z / zdot_climb + t_safety`` is the time the horizontal
    pattern starts (the reference reaches altitude) plus ``settle_s``."""
    return traj.arm_time_s + traj.climb_blend_s + settle_s


def crop_start(
    traj_id: Tensor,
    altitude_m: Tensor,
    traj: TrajectoryConfig,
    log_dt_s: float = 0.1,
    t_min_s: float = T_MIN_S,
    settle_s: float = SETTLE_S,
) -> Tensor:
    """First kept sample index ``[n]`` of each flight: the first 10 Hz sample at or after
    ``max(t_min, z / zdot_climb + t_safety)``.

    ``z`` is the flight altitude for fixed-altitude trajectories (the horizontal library). A
    vertical trajectory's climb *is* the flight (its label varies with altitude on purpose), so
    for it ``z = 0``: the crop drops only the take-off transient, the first ``t_min`` seconds.
    """
    climbing = ~fixed_altitude_mask(traj_id.device)[traj_id.long()]
    climb_s = torch.where(climbing, 0.0, altitude_m.to(torch.float64) / traj.climb_rate_m_s)
    t_crop = torch.clamp_min(climb_s + t_safety_s(traj, settle_s), t_min_s)
    return torch.ceil(t_crop / log_dt_s - 1e-9).to(torch.int64)


def split_cases(
    case_ids: Tensor, fractions: Sequence[float] = SPLIT_FRACTIONS, seed: int = SPLIT_SEED
) -> dict[str, Tensor]:
    """Partition the unique wind cases into train/val/test (a seeded permutation, then
    ``round(f * n)`` cases each for train and val, the rest test). Returns sorted case ids."""
    if len(fractions) != 3 or abs(sum(fractions) - 1.0) > 1e-6 or min(fractions) < 0:
        raise ValueError(f"split fractions={tuple(fractions)!r} must be three non-negative numbers summing to 1")
    cases = torch.unique(case_ids.cpu())
    n = cases.numel()
    perm = cases[torch.randperm(n, generator=torch.Generator().manual_seed(seed))]
    n_train = int(round(fractions[0] * n))
    n_val = int(round(fractions[1] * n))
    parts = (perm[:n_train], perm[n_train : n_train + n_val], perm[n_train + n_val :])
    return {name: torch.sort(p).values for name, p in zip(SPLITS, parts)}


def window_table(
    flights: Tensor, start: Tensor, length: Tensor, window: int = WINDOW, stride: int = 12
) -> Tensor:
    """``[W, 2]`` int64 ``(flight, end)`` of every window lying entirely in ``[start, length)`` of
    its flight: ends at ``start + window - 1 + k * stride``. ``flights``, ``start``, ``length``
    are ``[m]`` (row ids into the dataset and their crop start and valid length)."""
    first_end = start + window - 1
    count = torch.where(length - 1 >= first_end, (length - 1 - first_end) // stride + 1, 0)
    rows = torch.repeat_interleave(torch.arange(flights.numel()), count)
    offset = torch.arange(int(count.sum())) - torch.repeat_interleave(torch.cumsum(count, 0) - count, count)
    return torch.stack((flights[rows], first_end[rows] + offset * stride), -1)


class CaseBalancedSampler(Sampler[int]):
    """Draws a wind case uniformly among the cases that have windows, then one of that case's
    windows uniformly; ``num_samples`` draws per epoch (default: the number of windows), with
    replacement. Seeded: epoch ``e`` uses ``seed + e`` (``set_epoch``)."""

    def __init__(self, window_case: Tensor, num_samples: int | None = None, seed: int = 0):
        window_case = window_case.cpu()
        self.cases, inverse, self.counts = torch.unique(window_case, return_inverse=True, return_counts=True)
        self.order = torch.argsort(inverse, stable=True)  # window indices grouped by case
        self.offsets = torch.cumsum(self.counts, 0) - self.counts
        self.num_samples = int(num_samples if num_samples is not None else window_case.numel())
        self.seed = seed
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return self.num_samples

    def draw(self, num: int, generator: torch.Generator) -> Tensor:
        case = torch.randint(self.cases.numel(), (num,), generator=generator)
        u = torch.rand(num, generator=generator, dtype=torch.float64)
        k = torch.minimum((u * self.counts[case]).long(), self.counts[case] - 1)
        return self.order[self.offsets[case] + k]

    def __iter__(self) -> Iterator[int]:
        gen = torch.Generator().manual_seed(self.seed + self.epoch)
        yield from self.draw(self.num_samples, gen).tolist()


@dataclass
class Standardizer:
    """Per-channel ``(x - mean) / std`` (std floored at ``eps`` so constant channels pass through)."""

    mean: Tensor
    std: Tensor

    def __call__(self, x: Tensor) -> Tensor:
        return (x - self.mean.to(x.dtype)) / self.std.to(x.dtype)

    def inverse(self, x: Tensor) -> Tensor:
        return x * self.std.to(x.dtype) + self.mean.to(x.dtype)

    def state_dict(self) -> dict[str, Tensor]:
        return {"mean": self.mean, "std": self.std}


def sample_stats(values: Tensor, flights: Tensor, start: Tensor, length: Tensor, chunk: int = 128, eps: float = 1e-6) -> Standardizer:
    """Mean and std per channel of ``values[f, start_f : length_f]`` over ``flights`` (every
    cropped valid sample once), accumulated in float64 over chunks of flights."""
    c = values.shape[-1]
    total = torch.zeros(c, dtype=torch.float64)
    total_sq = torch.zeros(c, dtype=torch.float64)
    count = 0
    t_idx = torch.arange(values.shape[1])
    for i in range(0, flights.numel(), chunk):
        rows = flights[i : i + chunk]
        v = values[rows].to(torch.float64)
        m = (t_idx >= start[i : i + chunk, None]) & (t_idx < length[i : i + chunk, None])
        v = v[m]
        total += v.sum(0)
        total_sq += (v * v).sum(0)
        count += v.shape[0]
    if count == 0:
        raise ValueError("no samples to compute statistics from (empty training split?)")
    mean = total / count
    var = (total_sq / count - mean * mean).clamp_min(0.0)
    std = var.sqrt()
    std = torch.where(std < eps, torch.ones_like(std), std)
    return Standardizer(mean.to(torch.float32), std.to(torch.float32))


class WindowDataset(Dataset):
    """``(x [window, C], y [2])`` per window of ``table``; ``x`` standardised by ``standardize``
    if given. ``__getitems__`` gathers a whole batch with one indexing op (DataLoader uses it)."""

    def __init__(
        self,
        features: Tensor,
        labels: Tensor,
        table: Tensor,
        window: int = WINDOW,
        standardize: Standardizer | None = None,
    ):
        self.features, self.labels, self.table, self.window = features, labels, table, window
        self.standardize = standardize
        self._offsets = torch.arange(-(window - 1), 1)

    def __len__(self) -> int:
        return self.table.shape[0]

    def batch(self, idx: Tensor) -> tuple[Tensor, Tensor]:
        rows = self.table[idx]
        flight, end = rows[:, 0], rows[:, 1]
        x = torch.as_tensor(self.features[flight[:, None], end[:, None] + self._offsets])
        y = torch.as_tensor(self.labels[flight, end])
        if self.standardize is not None:
            x = self.standardize(x)
        return x, y

    def __getitem__(self, i: int) -> tuple[Tensor, Tensor]:
        x, y = self.batch(torch.tensor([i]))
        return x[0], y[0]

    def __getitems__(self, indices: list[int]) -> list[tuple[Tensor, Tensor]]:
        x, y = self.batch(torch.as_tensor(indices))
        return list(zip(x.unbind(0), y.unbind(0)))


def _cache_key(about: dict) -> dict:
    """What decides a feature cache's numbers: its shape, its channels (whose ``avg<w>_`` names
    carry the trailing windows) and the extractor's other settings. Its ``windows`` entry is left
    out: vertical caches written before that schema could have trailing means record the
    horizontal default there, unused."""
    return {**about, "extractor": {k: v for k, v in about["extractor"].items() if k != "windows"}}


def compute_features(
    record: TensorDict,
    extractor: FeatureExtractor,
    out: str | os.PathLike | None = None,
    chunk: int = 512,
    progress: bool = False,
) -> Tensor:
    """Features ``[n, T, C]`` of a dataset's ``record`` by :meth:`FeatureExtractor.scan` over
    chunks of flights. With ``out`` (a file path), the result is a memory-mapped tensor written
    to a temporary file and renamed into place; an existing ``out`` is loaded instead."""
    n, t_len = record.batch_size[:2]
    shape = torch.Size([n, t_len, extractor.num_channels])
    about = {"shape": list(shape), "extractor": asdict(extractor), "channels": list(extractor.channels)}
    if out is not None:
        out = Path(out)
        sidecar = out.parent / (out.name + ".json")
        if out.exists():
            saved = json.loads(sidecar.read_text()) if sidecar.exists() else None
            if saved is None or _cache_key(saved) != _cache_key(json.loads(json.dumps(about))):
                raise ValueError(f"{out} holds features of another extractor or dataset ({sidecar}); delete it to recompute")
            return MemoryMappedTensor.from_filename(out, dtype=torch.float32, shape=shape)
        tmp = out.parent / f".{out.name}.partial-{os.getpid()}"
        target: Tensor = MemoryMappedTensor.empty(shape, dtype=torch.float32, filename=tmp)
    else:
        target = torch.empty(shape, dtype=torch.float32)
    try:
        starts = range(0, n, chunk)
        if progress:
            from tqdm.auto import tqdm

            starts = tqdm(starts, desc=f"{extractor.schema} features", unit="chunk")
        for i in starts:
            rows = slice(i, min(i + chunk, n))
            raw = record.select(*extractor.raw_keys)[rows].apply(torch.as_tensor)  # the sensors nested under "meas"
            target[rows] = extractor.scan(raw)
    except BaseException:
        if out is not None:
            del target
            tmp.unlink(missing_ok=True)
        raise
    if out is not None:
        del target
        sidecar.write_text(json.dumps(about, indent=1) + "\n")
        os.replace(tmp, out)
        return MemoryMappedTensor.from_filename(out, dtype=torch.float32, shape=shape)
    return target


@dataclass
class WindowedData:
    """Everything the estimator's training needs from one dataset."""

    features: Tensor  # [n, T, C]
    labels: Tensor  # [n, T, 2] mean wind (north, east), m/s
    channels: tuple[str, ...]
    crop: Tensor  # [n] first kept sample
    length: Tensor  # [n] valid samples
    case_id: Tensor  # [n]
    split_cases: dict[str, Tensor]
    tables: dict[str, Tensor]  # split -> [W, 2] (flight, end)
    feature_stats: Standardizer  # training split only
    label_stats: Standardizer  # training split only
    window: int = WINDOW
    stride: int = 12

    def dataset(self, split: str, standardize: bool = True) -> WindowDataset:
        return WindowDataset(
            self.features,
            self.labels,
            self.tables[split],
            window=self.window,
            standardize=self.feature_stats if standardize else None,
        )

    def window_cases(self, split: str) -> Tensor:
        return self.case_id[self.tables[split][:, 0]]

    def sampler(self, split: str = "train", seed: int = 0, num_samples: int | None = None) -> CaseBalancedSampler:
        return CaseBalancedSampler(self.window_cases(split), num_samples=num_samples, seed=seed)


def prepare_windows(
    data: TensorDict,
    manifest: dict,
    features: Tensor,
    channels: Sequence[str],
    *,
    stride: int | None = None,
    window: int = WINDOW,
    split_seed: int = SPLIT_SEED,
    fractions: Sequence[float] = SPLIT_FRACTIONS,
    t_min_s: float = T_MIN_S,
    settle_s: float = SETTLE_S,
    exclude_crashed: bool = True,
    train_fraction: float = 1.0,
) -> WindowedData:
    """Crop, split by wind case, index the windows and fit the statistics (train only) for a
    dataset loaded by :func:`~quadwind_trl.data.generate.load_dataset` and its ``features``.

    ``train_fraction`` < 1 keeps that share of the training cases (a seeded subset, the same for
    every run with the same ``split_seed``); validation and test are unchanged, so a data-size
    experiment is scored on the same windows as the full run."""
    if not 0.0 < train_fraction <= 1.0:
        raise ValueError(f"train_fraction={train_fraction!r}; allowed: (0, 1]")
    regime = manifest["regime"]
    stride = STRIDE[regime] if stride is None else stride
    traj = TrajectoryConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in manifest["config"]["trajectories"].items()})
    crop = crop_start(
        torch.as_tensor(data["traj_id"]).clone(),
        torch.as_tensor(data["scenario", "altitude_m"]).clone(),
        traj,
        manifest["record_dt_s"],
        t_min_s,
        settle_s,
    )
    length = torch.as_tensor(data["length"]).clone()
    case_id = torch.as_tensor(data["case_id"]).clone()
    usable = ~torch.as_tensor(data["crashed"]).clone() if exclude_crashed else torch.ones_like(length, dtype=torch.bool)
    parts = split_cases(case_id, fractions, split_seed)
    if train_fraction < 1.0:
        train = parts["train"]
        keep = torch.randperm(train.numel(), generator=torch.Generator().manual_seed(split_seed + 1))
        parts["train"] = torch.sort(train[keep[: max(1, int(round(train_fraction * train.numel())))]]).values
    tables = {}
    for name, cases in parts.items():
        flights = torch.nonzero(torch.isin(case_id, cases) & usable).squeeze(-1)
        tables[name] = window_table(flights, crop[flights], length[flights], window, stride)
    train_flights = torch.unique(tables["train"][:, 0])
    labels = data["record", "mean_wind_ne"]
    return WindowedData(
        features=features,
        labels=labels,
        channels=tuple(channels),
        crop=crop,
        length=length,
        case_id=case_id,
        split_cases=parts,
        tables=tables,
        feature_stats=sample_stats(features, train_flights, crop[train_flights], length[train_flights]),
        label_stats=sample_stats(labels, train_flights, crop[train_flights], length[train_flights]),
        window=window,
        stride=stride,
    )

