"""Train the attention-GRU wind estimator on a generated flight dataset (paper, Section
"Wind Estimation"; design and budget in docs/estimator.md).

    python recipes/train_estimator.py --regime horizontal --data data/flights_horizontal
    python recipes/train_estimator.py --regime vertical   --data data/flights_vertical
    python recipes/train_estimator.py --regime vertical   --data data/flights_vertical_quick --quick

The best checkpoint goes to --out (default: quadwind_trl/checkpoints/estimator_<regime>.pt, the
shipped one; --quick: runs/estimator/estimator_<regime>_quick.pt) with its JSON manifest beside
it; CSV logs under runs/estimator/<exp_name>/. An interrupted run continues with --resume.

The inputs, the network and the loss can be changed for an experiment (write it under
results/experiments/, never over the shipped checkpoint), e.g. trailing means of 10, 30, 60 and
120 s, a two-layer GRU, half the training cases, the plain Huber loss:

    python recipes/train_estimator.py --regime horizontal --data data/flights_horizontal \
        --trailing-s 10 30 60 120 --out results/experiments/estimator/trailing120.pt
    ... --gru-layers 2    ... --train-fraction 0.5    ... --speed-weight 0 --direction-weight 0
    python recipes/train_estimator.py --regime vertical --data data/flights_vertical --trailing-s 10 30 \
        --out results/experiments/estimator/vertical_trailing_10_30.pt
"""
from __future__ import annotations

import argparse
import json
from quadwind_trl.manifest import command_line
import sys
import time
from dataclasses import replace
from pathlib import Path

import torch

from quadwind_trl.manifest import CHECKPOINT_DIR
from quadwind_trl.estimator.features import LOG_DT_S
from quadwind_trl.estimator.loss import EstimatorLossConfig
from quadwind_trl.estimator.training import full_config, load_estimator_data, quick_config, train_estimator


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--regime", required=True, choices=["horizontal", "vertical"])
    p.add_argument("--data", required=True, help="dataset directory (recipes/generate_flights.py)")
    p.add_argument("--quick", action="store_true", help="small smoke run (4 short epochs at batch 64)")
    p.add_argument("--out", default=None, help="checkpoint path (.pt); the manifest goes beside it (.json)")
    p.add_argument("--epochs", type=int, default=None, help="max epochs (default: horizontal 25, vertical 150)")
    p.add_argument("--windows-per-epoch", type=int, default=None, help="balanced-sampler draws per epoch (default: horizontal 80000, vertical 40000; 0 = the split's window count)")
    p.add_argument("--patience", type=int, default=None, help="early-stopping patience in epochs (default: vertical 25, horizontal none)")
    p.add_argument("--batch-size", type=int, default=None)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: torch's)")
    p.add_argument("--compile", action="store_true", help="torch.compile the training forward")
    p.add_argument("--resume", action="store_true", help="continue the interrupted run writing --out (none: start one)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing checkpoint at --out")
    p.add_argument("--window", type=int, default=None, help="samples per input window (default 60 = 6 s at 10 Hz)")
    p.add_argument("--trailing-s", type=float, nargs="*", default=None,
                   help="lengths of the features' trailing means, s (default: horizontal 10 30, vertical none; "
                        "the flag alone: none)")
    p.add_argument("--hidden", type=int, default=None, help="GRU and attention width (default 128)")
    p.add_argument("--gru-layers", type=int, default=None, help="GRU depth (default 1)")
    p.add_argument("--head-hidden", type=int, nargs=2, default=None, help="the MLP head's two widths (default 128 64)")
    p.add_argument("--train-fraction", type=float, default=None,
                   help="share of the training cases to train on (default 1; validation and test are unchanged)")
    p.add_argument("--speed-weight", type=float, default=None, help="the loss's speed term weight (default 0.03)")
    p.add_argument("--direction-weight", type=float, default=None, help="the loss's direction term weight (default 0.05)")
    p.add_argument("--log-dir", default="runs/estimator")
    p.add_argument("--exp-name", default=None, help="logger experiment name (default: unique per run)")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)

    overrides = {"seed": args.seed, "compile": args.compile}
    if args.epochs is not None:
        overrides["epochs"] = args.epochs
    if args.windows_per_epoch is not None:
        overrides["windows_per_epoch"] = args.windows_per_epoch or None
    if args.patience is not None:
        overrides["patience"] = args.patience or None
    if args.batch_size is not None:
        overrides["batch_size"] = args.batch_size
    for name in ("window", "hidden", "gru_layers", "train_fraction"):
        if getattr(args, name) is not None:
            overrides[name] = getattr(args, name)
    if args.head_hidden is not None:
        overrides["head_hidden"] = tuple(args.head_hidden)
    if args.trailing_s is not None:
        samples = [s / LOG_DT_S for s in args.trailing_s]
        if any(abs(n - round(n)) > 1e-6 for n in samples):
            p.error(f"--trailing-s {args.trailing_s}: each length must be a whole number of {LOG_DT_S} s samples")
        overrides["trailing_windows"] = tuple(int(round(n)) for n in samples)
    loss = {k: getattr(args, k) for k in ("speed_weight", "direction_weight") if getattr(args, k) is not None}
    try:
        if loss:
            overrides["loss"] = replace(EstimatorLossConfig(), **loss)
        cfg = (quick_config if args.quick else full_config)(args.regime, **overrides)
    except ValueError as err:
        p.error(str(err))
    out = Path(args.out) if args.out else (
        Path(args.log_dir) / f"estimator_{args.regime}_quick.pt" if args.quick else CHECKPOINT_DIR / f"estimator_{args.regime}.pt"
    )
    t0 = time.perf_counter()
    try:
        ed = load_estimator_data(args.data, args.regime, quick=args.quick, progress=not args.no_progress, window=cfg.window,
                                 trailing_windows=cfg.trailing_windows, train_fraction=cfg.train_fraction)
    except (FileNotFoundError, ValueError) as err:
        p.error(str(err))
    print(f"dataset {args.data}: {json.dumps(ed.info['split_cases'])} cases, {json.dumps(ed.info['split_windows'])} windows (stride {ed.windows.stride})", flush=True)
    try:
        result = train_estimator(
            ed, cfg, out, resume=args.resume, overwrite=args.overwrite, log_dir=args.log_dir,
            exp_name=args.exp_name, progress=not args.no_progress, command=command_line(sys.argv),
        )  # fmt: skip
    except (FileExistsError, FileNotFoundError, ValueError) as err:
        p.error(str(err))
    m = result.bundle.manifest["metrics"]
    print(
        f"best epoch {result.best_epoch}: val per-window vector RMSE {result.best_val['per_window_vector_rmse']:.3f} m/s, "
        f"direction MAE {result.best_val['direction_mae_deg']:.2f} deg"
    )
    if "per_window_vector_rmse" in m:
        if args.quick:
            print("toy scale (--quick): a handful of short flights and epochs. The skill scores compare the estimator with "
                  "predicting each flight's mean wind from a climatology of the same few cases, so at this scale they "
                  "are meaningless (large negative values are expected); the paper-scale ones are in docs/estimator.md.")
        print(
            f"test: per-window vector RMSE {m['per_window_vector_rmse']:.3f} m/s, per-flight {m['per_flight_vector_rmse']:.3f} m/s, "
            f"component-mean {m['component_mean_rmse']:.3f} m/s, direction MAE {m['direction_mae_deg']:.2f} deg, "
            f"corr N/E {m['corr_n']:.4f}/{m['corr_e']:.4f}, vector skill {m['vector_skill']:.3f}, speed skill {m['speed_skill']:.3f}"
        )
    print(f"wrote {out} (+ {out.with_suffix('.json').name}); training wall time {result.wall_time_s:.1f} s, total {time.perf_counter() - t0:.1f} s, threads {torch.get_num_threads()}")


if __name__ == "__main__":
    main()
