"""The ablation's statistics: hand-made decomposition, bootstrap coverage, win rate."""
from __future__ import annotations

import math

import torch

from quadwind_trl.evaluation.statistics import bootstrap_improvement_ci, decompose
from quadwind_trl.rl.paired import improvement, win_rate


def test_decomposition_arithmetic_by_hand():
    pd = torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)  # mean 2.0
    blind = torch.tensor([0.9, 1.5, 2.4], dtype=torch.float64)  # mean 1.6
    aware = torch.tensor([0.6, 1.2, 1.8], dtype=torch.float64)  # mean 1.2
    d = decompose(pd, blind, aware)
    assert math.isclose(d.improvement, 40.0)
    assert math.isclose(d.kinematic, 0.4, rel_tol=1e-12) and math.isclose(d.perception, 0.4, rel_tol=1e-12)
    assert math.isclose(d.kinematic_share, 50.0) and math.isclose(d.perception_share, 50.0)
    assert math.isclose(d.perception_relative, 25.0)  # 0.4 of 1.6
    # the paper's horizontal aggregate: 1.315 / 0.985 / 0.684 -> 52.3 / 47.7 % (paper: 52.4 / 47.6)
    d = decompose(torch.tensor([1.315]), torch.tensor([0.985]), torch.tensor([0.684]))
    assert abs(d.perception_share - 47.7) < 0.1 and abs(d.improvement - 48.0) < 0.05
    # a counterproductive perception step has a negative share (the paper's vertical U = 3)
    d = decompose(torch.tensor([0.576]), torch.tensor([0.398]), torch.tensor([0.409]))
    assert d.perception_share < 0 and abs(d.perception_share + 6.6) < 0.2


def test_win_rate_counts_strict_wins():
    assert win_rate(torch.tensor([1.0, 1.0, 1.0]), torch.tensor([0.5, 1.0, 2.0])) == (1, 3)
    assert math.isclose(improvement(torch.tensor([2.0, 2.0]), torch.tensor([1.0, 1.0])), 50.0)


def test_bootstrap_interval_covers_the_true_improvement_at_its_nominal_rate():
    """Paired lognormal RMSEs with a known population improvement: the 95 % interval should
    contain it in about 95 % of repeated experiments (the percentile bootstrap of a ratio of
    means is slightly liberal at n = 100; we accept 89-99 %)."""
    gen = torch.Generator().manual_seed(1)
    trials, n = 300, 100
    mu, sigma, factor = 0.0, 0.6, 0.6
    # PD ~ lognormal; RL = factor * PD * lognormal noise (median 1, so E[ratio] is known)
    noise_sigma = 0.3
    true_impr = 100.0 * (1.0 - factor * math.exp(noise_sigma**2 / 2))
    covered = 0
    for t in range(trials):
        pd = torch.exp(mu + sigma * torch.randn(n, generator=gen, dtype=torch.float64))
        rl = factor * pd * torch.exp(noise_sigma * torch.randn(n, generator=gen, dtype=torch.float64))
        lo, hi = bootstrap_improvement_ci(pd, rl, resamples=1000, seed=t)
        covered += lo <= true_impr <= hi
    rate = covered / trials
    assert 0.89 <= rate <= 0.99, rate
