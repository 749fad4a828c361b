"""Can the wind estimator run incrementally, and what does the exact windowed estimate cost?

    python bench/estimator_streaming.py                  # shipped horizontal estimator, 1 thread

The network runs its GRU from a zero state over each 60-sample window (paper: the window is the
model's whole input). A streaming estimator would carry the GRU state from tick to tick, so that
each 10 Hz tick costs one GRU step; its state then holds the whole episode, not the window, and
its output is another function of the data. Part 1 measures the gap on flights: PD flights of the
horizontal training env (4 rows, 25 s from the pattern start), at each tick after the window has
filled, the windowed estimate (what ``WindEstimate`` computes) against the streaming one (GRU
state carried from the episode's first sample, attention over the last 60 carried states), in m/s.

Part 2 measures the exact alternatives per call of ``B`` windows, windows per second:
``eager`` (``EstimatorBundle.predict``: ``nn.GRU``), ``compiled`` (``torch.compile`` of the
network), and ``cached_input`` (the GRU's input projection ``W_ih x + b_ih`` of each sample kept
from the tick it arrived, so a tick re-runs only the recurrence: equal to the windowed estimate to
float rounding, but not bit for bit, so adopting it changes replayed flights). Prints::

    estimator_streaming gap_m_s_mean=... gap_m_s_median=... gap_m_s_max=... ticks=...
    estimator_speed B=1024 variant=eager windows_per_s=... ms_per_call=... max_abs_diff=0 load_1min=...
"""
from __future__ import annotations

import argparse
import time

import torch
from machine import load_1min, machine_line
from torch import Tensor, nn

from quadwind_trl.estimator import load_estimator
from quadwind_trl.quick import QuickFlights
from quadwind_trl.regimes import regime_config
from quadwind_trl.rl.envs import make_env, wind_estimate


def seconds_per_call(fn, min_time: float = 3.0) -> float:
    fn()  # warm-up
    calls, start = 0, time.perf_counter()
    while calls < 3 or time.perf_counter() - start < min_time:
        fn()
        calls += 1
    return (time.perf_counter() - start) / calls


def gru_recurrence(x_proj: Tensor, gru: nn.GRU) -> tuple[Tensor, Tensor]:
    """``nn.GRU``'s single-layer recurrence from a zero state, given the input projections
    ``[B, T, 3H]`` (gate order r, z, n as in PyTorch): ``(states [B, T, H], last [B, H])``."""
    h = x_proj.new_zeros(x_proj.shape[0], gru.hidden_size)
    states = []
    for t in range(x_proj.shape[1]):
        gh = torch.addmm(gru.bias_hh_l0, h, gru.weight_hh_l0.t())
        xr, xz, xn = x_proj[:, t].chunk(3, -1)
        hr, hz, hn = gh.chunk(3, -1)
        r, z = torch.sigmoid(xr + hr), torch.sigmoid(xz + hz)
        n = torch.tanh(xn + r * hn)
        h = (1 - z) * n + z * h
        states.append(h)
    return torch.stack(states, 1), h


@torch.no_grad()
def streaming_gap(bundle, steps: int) -> Tensor:
    """``[rows, ticks]`` |streaming - windowed| (m/s) on PD flights."""
    model = bundle.model
    flights = QuickFlights(pattern_s=float(steps) / 10.0 + 5.0)
    env = make_env("horizontal", bundle, 4, compile_step=False, start="pattern",
                   config=flights.config(regime_config("horizontal")))
    west, td, samples = wind_estimate(env), env.reset(), []
    for _ in range(steps):  # one decision = one 10 Hz tick per row
        td["action"] = torch.zeros(4, 4)
        _, td = env.step_and_maybe_reset(td)
        samples.append(west.ring.windows(torch.arange(4))[:, -1].clone())  # each tick's newest sample
    z = (torch.stack(samples, 1) - bundle.feature_mean) / bundle.feature_std
    carried, _ = model.gru(z)
    window = model.cfg.window
    gaps = []
    for t in range(window - 1, steps):
        windowed = model(z[:, t - window + 1 : t + 1])
        context, _ = model.attention(carried[:, t - window + 1 : t + 1], carried[:, t])
        streamed = model.head(torch.cat((context, carried[:, t]), -1))
        gaps.append(((streamed - windowed) * bundle.label_std).norm(dim=-1))
    return torch.stack(gaps, 1)


@torch.no_grad()
def speeds(bundle, batch: int) -> list[dict]:
    model = bundle.model
    z = torch.randn(batch, model.cfg.window, model.cfg.in_channels)
    reference = model(z)
    x_proj = nn.functional.linear(z, model.gru.weight_ih_l0, model.gru.bias_ih_l0)  # kept per sample

    def cached_input() -> Tensor:
        states, last = gru_recurrence(x_proj, model.gru)
        context, _ = model.attention(states, last)
        return model.head(torch.cat((context, last), -1))

    compiled = torch.compile(model, dynamic=False)
    rows = []
    for name, fn in (("eager", lambda: model(z)), ("compiled", lambda: compiled(z)), ("cached_input", cached_input)):
        s = seconds_per_call(fn)
        rows.append({"B": batch, "variant": name, "windows_per_s": round(batch / s), "ms_per_call": round(1e3 * s, 2),
                     "max_abs_diff": f"{(fn() - reference).abs().max().item():.1e}", "load_1min": round(load_1min(), 2)})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batches", type=int, nargs="+", default=[64, 1024], help="windows per call")
    parser.add_argument("--ticks", type=int, default=250, help="10 Hz ticks flown for the streaming gap")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(machine_line(args.threads), flush=True)
    torch.manual_seed(0)
    bundle = load_estimator("horizontal")
    gap = streaming_gap(bundle, args.ticks)
    print(f"estimator_streaming gap_m_s_mean={gap.mean():.3f} gap_m_s_median={gap.median():.3f} "
          f"gap_m_s_max={gap.max():.3f} ticks={gap.numel()}", flush=True)
    for b in args.batches:
        for row in speeds(bundle, b):
            print("estimator_speed " + " ".join(f"{k}={v}" for k, v in row.items()), flush=True)


if __name__ == "__main__":
    main()
