"""The spike-gated EMA post-filter (quadwind_trl.estimator.ema): step response, spike gating, the
online step equals the offline scan, row resets."""
from __future__ import annotations

import math

import torch

from quadwind_trl.estimator.ema import EMAConfig, ema_init, ema_reset_rows, ema_scan, ema_step

NO_GATE = dict(spike_factor=1e9)


def test_step_response_reaches_63_percent_after_tau():
    tau, dt = 1.0, 0.1
    x = torch.zeros(1, 60, 2)
    x[:, 1:] = torch.tensor([3.0, -2.0])  # a step at sample 1
    y = ema_scan(x, EMAConfig(tau_s=tau, dt_s=dt, **NO_GATE))
    k = round(tau / dt)  # sample j >= 1 has made j updates toward the step: y_j = 1 - (1 - alpha)^j
    frac = y[0, k] / torch.tensor([3.0, -2.0])
    torch.testing.assert_close(frac, torch.full((2,), 1 - math.exp(-1.0)), rtol=1e-5, atol=1e-6)
    # the exact discrete response 1 - (1 - alpha)^k, alpha = 1 - exp(-dt / tau), at every sample
    alpha = 1 - math.exp(-dt / tau)
    expect = 1 - (1 - alpha) ** torch.arange(1, 60, dtype=torch.float64)
    torch.testing.assert_close(y[0, 1:, 0].double() / 3.0, expect, rtol=1e-5, atol=1e-6)


def test_step_response_with_a_large_initial_scale_is_not_gated():
    """Gating on, but the running scale is large: the step is an ordinary innovation."""
    x = torch.zeros(1, 40, 2)
    x[:, 1:, 0] = 1.0
    y = ema_scan(x, EMAConfig(tau_s=2.0, dt_s=0.1, initial_scale=100.0))
    torch.testing.assert_close(y[0, 20, 0], torch.tensor(1 - math.exp(-1.0)), rtol=1e-4, atol=1e-5)


def test_single_spike_barely_moves_the_output():
    gen = torch.Generator().manual_seed(0)
    x = torch.tensor([5.0, 2.0]) + 0.2 * torch.randn(1, 300, 2, generator=gen)
    x[0, 200] = torch.tensor([50.0, -40.0])  # one outlier (about 60 m/s off)
    cfg = EMAConfig(tau_s=1.0, dt_s=0.1, initial_scale=0.3)
    gated = ema_scan(x, cfg)
    ungated = ema_scan(x, EMAConfig(tau_s=1.0, dt_s=0.1, **NO_GATE))
    jump_gated = (gated[0, 200] - gated[0, 199]).norm()
    jump_ungated = (ungated[0, 200] - ungated[0, 199]).norm()
    assert jump_ungated > 5.0  # alpha (0.095) x 60 m/s
    assert jump_gated < 0.15  # at most alpha x 3 x scale (scale ~ the 0.2-0.3 m/s innovations)
    assert (gated[0, 200:] - torch.tensor([5.0, 2.0])).norm(dim=-1).max() < 0.5


def test_a_lasting_change_is_followed_after_the_scale_adapts():
    x = torch.zeros(1, 600, 2)
    x[:, 100:, 0] = 10.0
    y = ema_scan(x, EMAConfig(tau_s=1.0, dt_s=0.1, initial_scale=0.1))
    assert abs(float(y[0, -1, 0]) - 10.0) < 0.05


def test_tau_zero_is_raw_and_scan_equals_online_steps():
    x = torch.randn(3, 50, 2)
    torch.testing.assert_close(ema_scan(x, EMAConfig(tau_s=0.0)), x)
    cfg = EMAConfig(tau_s=3.0)
    state = ema_init(3, 2)
    online = []
    for t in range(50):
        state, y = ema_step(state, x[:, t], cfg)
        online.append(y)
    assert torch.equal(torch.stack(online, 1), ema_scan(x, cfg))


def test_reset_rows_restarts_only_those_rows():
    cfg = EMAConfig(tau_s=3.0)
    state = ema_init(2, 2)
    for _ in range(20):
        state, y = ema_step(state, torch.tensor([[1.0, 1.0], [2.0, 2.0]]), cfg)
    state = ema_reset_rows(state, torch.tensor([True, False]))
    state, y = ema_step(state, torch.tensor([[7.0, 7.0], [7.0, 7.0]]), cfg)
    torch.testing.assert_close(y[0], torch.tensor([7.0, 7.0]))  # restarted: the first sample
    assert float(y[1, 0]) < 3.0  # still filtering (and gated: a 5 m/s jump on a ~0 scale)


def test_new_policies_train_with_the_tau_chosen_on_validation(tmp_path):
    from quadwind_trl.estimator import DEFAULT_TAU_S, EstimatorBundle, untrained_estimator
    from quadwind_trl.rl.envs import validated_tau_s

    bundle = untrained_estimator("horizontal")
    assert validated_tau_s(bundle) == DEFAULT_TAU_S  # never evaluated: the paper's
    bundle.manifest["evaluation"] = {"val_best_tau_s": 20.0}  # what evaluate_estimator --update-checkpoint writes
    bundle.save(tmp_path / "est.pt")
    assert validated_tau_s(EstimatorBundle.load(tmp_path / "est.pt")) == 20.0
