"""Generate a PD-flown flight-log dataset (paper, Sections "Wind Estimation": 1000 LHS wind cases
x the regime's trajectory library).

    python recipes/generate_flights.py --regime horizontal            # 1000 cases x 5 trajectories
    python recipes/generate_flights.py --regime vertical              # 1000 cases x 4 trajectories
    python recipes/generate_flights.py --regime horizontal --quick    # tiny smoke-test set
    python recipes/generate_flights.py --regime horizontal --turbulence-layout paper_grid  # the paper's 64^3 cube

The dataset goes to ``--out`` (default ``data/flights_<regime>[_paper_grid][_quick]``) through a temporary
directory renamed into place at the end (see ``quadwind_trl/data/generate.py``; format in
``docs/features.md``), committing each chunk of flights as it goes: an interrupted run
(Ctrl-C, SIGTERM) continues with ``--resume``. Same arguments => byte-identical dataset.
"""
from __future__ import annotations

import argparse
from quadwind_trl.manifest import command_line
import sys
import time
from dataclasses import replace

import torch

from quadwind_trl.config import TURBULENCE_LAYOUTS
from quadwind_trl.regimes import DATASET_SEED
from quadwind_trl.data.generate import GenerationSpec, Regime, dataset_bytes, describe, generate_dataset, load_dataset, quick_spec


def build_spec(regime: Regime, quick: bool, cases: int | None, seed: int,
               layout: str = "full") -> tuple[GenerationSpec, list[str]]:
    """The dataset's spec, with its turbulence field's ``layout``, and (``quick``) the lines saying
    what differs from the paper-size dataset. The layout is part of the spec's config, so it is
    recorded in the manifest and in the resume fingerprint (a cube run never resumes as a full one)."""
    if quick:
        spec, changes = quick_spec(regime, seed=seed, cases=cases or 3)
    else:
        spec, changes = GenerationSpec(regime=regime, cases=cases or 1000, seed=seed), []
    # "full" is the default layout: the spec, and so the dataset, stay what they were
    turbulence = replace(spec.config.turbulence, layout=layout)
    return replace(spec, config=replace(spec.config, turbulence=turbulence)), changes


def default_out(regime: Regime, quick: bool, layout: str) -> str:
    """``data/flights_<regime>[_<layout>][_quick]``: a layout other than "full" never lands on the shipped name."""
    suffix = "" if layout == "full" else f"_{layout}"
    return f"data/flights_{regime}{suffix}{'_quick' if quick else ''}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--regime", required=True, choices=["horizontal", "vertical"])
    parser.add_argument("--quick", action="store_true", help="tiny set: 3 cases, short flights (prints what changed)")
    parser.add_argument("--out", default=None, help="output directory (default data/flights_<regime>[_paper_grid][_quick])")
    parser.add_argument("--cases", type=int, default=None, help="wind cases (default 1000; --quick: 3)")
    parser.add_argument("--seed", type=int, default=None,
                        help="LHS design seed (default: the regime's training design, quadwind_trl.regimes.DATASET_SEED; "
                             "DATASET_UNSEEN_SEED makes the independent design for generalisation tests)")
    parser.add_argument("--turbulence-layout", choices=TURBULENCE_LAYOUTS, default="full",
                        help="TurbulenceConfig.layout: 'full' (default: the shipped datasets) or 'paper_grid' (the "
                             "paper's 64^3 periodic cube over 1200 m, trilinear; docs/atmosphere.md 2.2; its bank "
                             "takes about 35 s to build)")
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

    spec, changes = build_spec(args.regime, args.quick, args.cases, seed, args.turbulence_layout)
    if args.quick:
        print("--quick changes from the paper-size dataset:")
        for line in changes:
            print(f"  {line}")
    out = args.out or default_out(args.regime, args.quick, args.turbulence_layout)
    n = spec.cases * len(spec.trajectories)
    print(f"{args.regime}: {spec.cases} cases x {len(spec.trajectories)} trajectories = {n} flights, "
          f"turbulence layout {args.turbulence_layout} -> {out}", flush=True)
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
