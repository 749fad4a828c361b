"""What the residual policy adds on a classical base: every training seed's paired ablation of
the residual trained on that base, against the base alone and the paper's PD, per wind speed,
pattern and flight phase, with the wind estimate's worth on that base.

    python recipes/residual_value.py --base dob

Reads ``SEEDS/seed<k>/ablation_<sweep>.json`` (default ``results/residual/<base>/``: per seed the
paired ablation of the policies trained with ``--base-controller <base>``, wind-aware and trained
blind, e.g. ``python recipes/ablation.py --policy runs/h_dob_s0/policy.pt --blind-policy
runs/h_dob_blind_s0/policy.pt --controllers pd aware trained_blind --results results/residual/dob/seed0``)
and the classical controllers' file of each sweep (``--classical``, default ``results/classical``),
which flew the paper's PD and the base alone on the same episodes. Flies nothing. Writes
``results/residual_<base>.json``; ``python recipes/report.py`` renders it
(``quadwind_trl/studies/residual.py`` says what is compared).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from quadwind_trl.manifest import command_line, git_commit, repo_relative, write_json
from quadwind_trl.outputs import hold_for_command
from quadwind_trl.regimes import CLASSICAL_CONTROLLERS, SWEEPS
from quadwind_trl.studies.perception import read_seeds
from quadwind_trl.studies.residual import analyse_residual


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--base", required=True, choices=CLASSICAL_CONTROLLERS, help="the classical base the residuals trained on")
    parser.add_argument("--seeds", type=Path, default=None, help="the residual's seed folders (default results/residual/<base>)")
    parser.add_argument("--classical", type=Path, default=Path("results/classical"))
    parser.add_argument("--sweeps", nargs="+", default=list(SWEEPS), choices=list(SWEEPS),
                        help="default: every sweep the seeds flew")
    parser.add_argument("--out", type=Path, default=None, help="default results/residual_<base>.json")
    parser.add_argument("--resamples", type=int, default=10_000, help="bootstrap resamples per paired interval")
    args = parser.parse_args()
    seeds_dir = args.seeds or Path("results/residual") / args.base
    out = args.out or Path(f"results/residual_{args.base}.json")
    commit = git_commit()
    hold_for_command(out, what="residual value", hint="wait for it to finish, or choose another --out")
    sweeps, inputs = {}, {}
    for sweep in args.sweeps:
        results, read = read_seeds(seeds_dir, sweep)
        classical_file = args.classical / f"ablation_{sweep}.json"
        if not results:
            continue
        if not classical_file.exists():
            parser.error(f"{classical_file} is missing: the {sweep} sweep's classical rows pair the residual with "
                         f"its base and PD (python recipes/ablation.py --sweeps {sweep} --controllers pd {args.base} "
                         f"--results {args.classical})")
        classical = json.loads(classical_file.read_text())
        sweeps[sweep] = analyse_residual(results, classical, args.base, resamples=args.resamples)
        inputs[sweep] = {"seeds": read, "classical": {"file": repo_relative(classical_file),
                                                      "git_commit": classical.get("git_commit")}}
    if not sweeps:
        parser.error(f"no seed<k>/ablation_<sweep>.json under {seeds_dir} for the sweeps {', '.join(args.sweeps)}")
    write_json(out, {"command": command_line(sys.argv), "git_commit": commit, "base": args.base,
                     "resamples": args.resamples, "inputs": inputs, "sweeps": sweeps})
    for sweep, analysis in sweeps.items():
        every = analysis["by_wind"]["all"]
        for name in ("aware_vs_base", "trained_blind_vs_base", "aware_vs_trained_blind", "aware_vs_paper_pd"):
            if name in every:
                s = every[name]["across_seeds"]
                print(f"{sweep}: {name}, xy, {s['n_seeds']} seeds: {s['mean']:+.1f} % "
                      f"(seeds {s['min']:+.1f} to {s['max']:+.1f}; 95 % t-interval {s['t_low']:+.1f} to {s['t_high']:+.1f})")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
