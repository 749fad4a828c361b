"""Paired statistics of the three-way ablation (paper, Sections "Baseline and the perception
ablation" and "Evaluation protocol").

All inputs are per-episode RMSEs of matched episodes (the same scenarios, identical replayed
physics), one tensor per controller, aligned by episode. The two paired statistics the trainer
reports too, :func:`~quadwind_trl.rl.paired.improvement` and :func:`~quadwind_trl.rl.paired.win_rate`,
live with the paired flights in :mod:`quadwind_trl.rl.paired`; this module adds the bootstrap
interval, the decomposition and the full paired summary.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Mapping, Sequence

import torch
from scipy.stats import t as student_t
from torch import Tensor

from ..rl.paired import improvement, win_rate


def bootstrap_improvement_ci(
    baseline: Tensor, other: Tensor, resamples: int = 10_000, level: float = 0.95, seed: int = 0
) -> tuple[float, float]:
    """Percentile bootstrap interval of :func:`improvement` over matched pairs: episodes are
    resampled with replacement, each keeping its pair, so the pairing's correlation is kept."""
    n = baseline.numel()
    gen = torch.Generator().manual_seed(seed)
    idx = torch.randint(0, n, (resamples, n), generator=gen)
    b = baseline.double()[idx].mean(-1)
    o = other.double()[idx].mean(-1)
    stats = 100.0 * (1.0 - o / b)
    alpha = (1.0 - level) / 2.0
    lo, hi = torch.quantile(stats, torch.tensor([alpha, 1.0 - alpha], dtype=torch.float64)).tolist()
    return lo, hi


@dataclass(frozen=True)
class Decomposition:
    """The three-way split of an improvement, on group means (m and percent)."""

    pd: float
    blind: float
    aware: float
    improvement: float  # % of PD removed by the wind-aware policy
    kinematic: float  # m: PD - wind-blind RL
    perception: float  # m: wind-blind RL - wind-aware RL
    kinematic_share: float  # % of the total improvement (PD - aware)
    perception_share: float  # %
    perception_relative: float  # % reduction from wind-blind to wind-aware RL

    def as_dict(self) -> dict:
        return asdict(self)


def decompose(pd: Tensor, blind: Tensor, aware: Tensor) -> Decomposition:
    """Kinematic and wind-perception components of the improvement, from matched episodes.

    The components are additive by construction: ``(PD - blind) + (blind - aware) = PD - aware``;
    the shares divide them by that total (a share is negative when a step made things worse).
    """
    m_pd, m_blind, m_aware = (x.double().mean().item() for x in (pd, blind, aware))
    total = m_pd - m_aware
    kin, perc = m_pd - m_blind, m_blind - m_aware
    share = (lambda part: 100.0 * part / total) if total != 0 else (lambda part: float("nan"))
    return Decomposition(
        pd=m_pd,
        blind=m_blind,
        aware=m_aware,
        improvement=100.0 * total / m_pd,
        kinematic=kin,
        perception=perc,
        kinematic_share=share(kin),
        perception_share=share(perc),
        perception_relative=100.0 * perc / m_blind,
    )


def paired_summary(baseline: Tensor, other: Tensor, resamples: int = 10_000, seed: int = 0) -> dict:
    """Mean +- std of both, improvement with its bootstrap 95 % interval, and the win count."""
    lo, hi = bootstrap_improvement_ci(baseline, other, resamples=resamples, seed=seed)
    wins, n = win_rate(baseline, other)
    return {
        "n": n,
        "baseline_mean": baseline.double().mean().item(),
        "baseline_std": baseline.double().std().item(),
        "other_mean": other.double().mean().item(),
        "other_std": other.double().std().item(),
        "improvement": improvement(baseline, other),
        "ci_low": lo,
        "ci_high": hi,
        "wins": wins,
        "win_rate": wins / n,
    }


# --- across training seeds: one value per seed, an interval over the seeds ----------------------


def t_interval(values: Sequence[float], level: float = 0.95) -> tuple[float, float]:
    """Student-t interval of the mean of ``values`` (n - 1 degrees of freedom); NaN with fewer
    than two values."""
    n = len(values)
    if n < 2:
        return math.nan, math.nan
    x = torch.tensor(values, dtype=torch.float64)
    half = float(student_t.ppf(0.5 + level / 2, n - 1)) * x.std().item() / math.sqrt(n)
    return x.mean().item() - half, x.mean().item() + half


def across_seeds(per_seed: Mapping[str, float]) -> dict:
    """Seed count, mean, range and t-interval of the finite seed-level values."""
    values = [v for v in per_seed.values() if math.isfinite(v)]
    if not values:
        return {"n_seeds": 0, "mean": math.nan, "min": math.nan, "max": math.nan, "t_low": math.nan, "t_high": math.nan}
    low, high = t_interval(values)
    return {"n_seeds": len(values), "mean": sum(values) / len(values), "min": min(values), "max": max(values),
            "t_low": low, "t_high": high}
