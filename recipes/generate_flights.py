"""Generate a PD-flown flight-log dataset (paper, Sections "Wind Estimation": 1000 LHS wind cases
x the regime's trajectory library).

    python recipes/generate_flights.py --regime horizontal            # 1000 cases x 5 trajectories
    python recipes/generate_flights.py --regime vertical              # 1000 cases x 4 trajectories
    python recipes/generate_flights.py --regime horizontal --quick    # tiny smoke-test set

The dataset goes to ``--out`` (default ``data/flights_<regime>[_quick]``) through a temporary
directory renamed into place at the end (see ``quadwind_trl/data/generate.py``; format in
``docs/features.md``), committing each chunk of flights as it goes: an interrupted run
(Ctrl-C, SIGTERM) continues with ``--resume``. Same arguments => byte-identical dataset.
"""
from __future__ import annotations

import argparse
from quadwind_trl.manifest import command_line
import sys
import time

import torch

from quadwind_trl.regimes import DATASET_SEED
from quadwind_trl.data.generate import GenerationSpec, dataset_bytes, describe, generate_dataset, load_dataset, quick_spec


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--regime", required=True, choices=["horizontal", "vertical"])
    parser.add_argument("--quick", action="store_true", help="tiny set: 3 cases, short flights (prints what changed)")
    parser.add_argument("--out", default=None, help="output directory (default data/flights_<regime>[_quick])")
    parser.add_argument("--cases", type=int, default=None, help="wind cases (default 1000; --quick: 3)")
    parser.add_argument("--seed", type=int, default=None,
                        help="LHS design seed (default: the regime's training design, quadwind_trl.regimes.DATASET_SEED; "
                             "DATASET_UNSEEN_SEED makes the independent design for generalisation tests)")
    parser.add_argument("--batch", type=int, default=2048, help="max env batch (balanced over chunks)")
    parser.add_argument("--compile", action="store_true", help="torch.compile the simulator step")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: torch's)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing dataset at --out")
    parser.add_argument("--resume", action="store_true",
                        help="continue an interrupted run (same arguments) from its last finished chunk")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    seed = DATASET_SEED[args.regime] if args.seed is None else args.seed

    if args.quick:
        spec, changes = quick_spec(args.regime, seed=seed, cases=args.cases or 3)
        print("--quick changes from the paper-size dataset:")
        for line in changes:
            print(f"  {line}")
    else:
        spec = GenerationSpec(regime=args.regime, cases=args.cases or 1000, seed=seed)
    out = args.out or f"data/flights_{args.regime}{'_quick' if args.quick else ''}"
    n = spec.cases * len(spec.trajectories)
    print(f"{args.regime}: {spec.cases} cases x {len(spec.trajectories)} trajectories = {n} flights -> {out}", flush=True)
    start = time.perf_counter()
    try:
        path = generate_dataset(
            out,
            spec,
            max_batch=args.batch,
            device=args.device,
            compile_step=args.compile,
            overwrite=args.overwrite,
            resume=args.resume,
            progress=not args.no_progress,
            command=command_line(sys.argv),
        )
    except (FileExistsError, ValueError) as err:
        parser.error(str(err))
    except KeyboardInterrupt:  # SIGINT or SIGTERM: the library has said what it kept
        raise SystemExit(130) from None
    elapsed = time.perf_counter() - start
    data, manifest = load_dataset(path)
    print(describe(data, manifest))
    print(f"wrote {path} ({dataset_bytes(path) / 1e6:.1f} MB) in {elapsed:.1f} s, threads={torch.get_num_threads()}")


if __name__ == "__main__":
    main()
