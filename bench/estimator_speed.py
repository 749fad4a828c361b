"""Training throughput and frozen-estimator inference latency of the attention-GRU estimator.

    python bench/estimator_speed.py --threads 1
    python bench/estimator_speed.py --threads 2 --channels 48 --compile 0 1

Training: one optimiser step (forward, loss, backward, gradient clipping, Adam) on a batch of 256
standardised windows [256, 60, C], plus the window gather from a feature array of the size of a
small dataset (``--gather``), in windows per second. Inference: ``EstimatorBundle.predict``-style
frozen model (eval, no grad) at batch 1, 256 and 4096, in ms per call and windows per second.
Eager and ``torch.compile``. Prints one parseable line per configuration::

    estimator_speed kind=train channels=48 compile=0 threads=1 batch=256 ms_per_call=... windows_per_s=...
"""
from __future__ import annotations

import argparse
import time

import torch
from machine import load_1min, machine_line

from quadwind_trl.estimator import AttentionGRUEstimator, EstimatorConfig, EstimatorLoss


def timed(fn, min_time: float, min_calls: int = 3) -> float:
    """Seconds per call of ``fn`` (after it has been warmed up by the caller)."""
    calls, start = 0, time.perf_counter()
    while True:
        fn()
        calls += 1
        elapsed = time.perf_counter() - start
        if calls >= min_calls and elapsed >= min_time:
            return elapsed / calls


def bench_train(channels: int, compile_model: bool, batch: int, min_time: float, gather: bool) -> float:
    torch.manual_seed(0)
    model = AttentionGRUEstimator(EstimatorConfig(in_channels=channels))
    fwd = torch.compile(model) if compile_model else model
    loss_fn = EstimatorLoss(torch.zeros(2), torch.full((2,), 5.0))
    opt = torch.optim.Adam(model.parameters(), lr=3e-4, weight_decay=1e-5)
    feats = torch.randn(200, 2000, channels)  # ~77 MB: the gather touches scattered rows, as in training
    labels = torch.randn(200, 2000, 2)
    offsets = torch.arange(-59, 1)

    def step():
        if gather:
            f = torch.randint(0, 200, (batch,))
            e = torch.randint(59, 2000, (batch,))
            x = feats[f[:, None], e[:, None] + offsets]
            y = labels[f, e]
        else:
            x, y = xs, ys
        x = x + 0.05 * torch.randn_like(x)
        loss, _ = loss_fn(fwd(x), y)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()

    xs, ys = torch.randn(batch, 60, channels), torch.randn(batch, 2)
    for _ in range(3):
        step()
    return timed(step, min_time)


@torch.no_grad()
def bench_infer(channels: int, compile_model: bool, batch: int, min_time: float) -> float:
    torch.manual_seed(0)
    model = AttentionGRUEstimator(EstimatorConfig(in_channels=channels)).eval().requires_grad_(False)
    fwd = torch.compile(model) if compile_model else model
    x = torch.randn(batch, 60, channels)
    for _ in range(3):
        fwd(x)
    return timed(lambda: fwd(x), min_time)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--channels", type=int, nargs="+", default=[48, 22])
    p.add_argument("--compile", type=int, nargs="+", default=[0, 1])
    p.add_argument("--batches", type=int, nargs="+", default=[1, 256, 4096])
    p.add_argument("--train-batch", type=int, default=256)
    p.add_argument("--min-time", type=float, default=3.0, help="seconds of timing per configuration")
    p.add_argument("--no-gather", action="store_true", help="train on one fixed batch (model cost only)")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    print(machine_line(args.threads), flush=True)
    for c in args.channels:
        for comp in args.compile:
            s = bench_train(c, bool(comp), args.train_batch, args.min_time, not args.no_gather)
            print(
                f"estimator_speed kind=train channels={c} compile={comp} threads={args.threads} batch={args.train_batch} "
                f"gather={int(not args.no_gather)} ms_per_call={s * 1e3:.2f} windows_per_s={args.train_batch / s:.0f} load_1min={load_1min():.2f}",
                flush=True,
            )
            for b in args.batches:
                s = bench_infer(c, bool(comp), b, args.min_time)
                print(
                    f"estimator_speed kind=infer channels={c} compile={comp} threads={args.threads} batch={b} "
                    f"ms_per_call={s * 1e3:.3f} windows_per_s={b / s:.0f} load_1min={load_1min():.2f}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
