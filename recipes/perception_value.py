"""What the wind estimate is worth to the controller: every training seed's paired
ablation, compared across seeds, per wind speed and per flight phase; with policy variants.

    python recipes/perception_value.py
    python recipes/perception_value.py --variant no_attitude_accel=results/experiments/perception/no_attitude_accel \\
        --variant ema_tau_3s=results/experiments/perception/ema_tau_3s

Reads ``SEEDS/seed<k>/ablation_<sweep>.json`` (``recipes/reproduce.py --full``: per seed, the
wind-aware and the trained-blind policies, and an oracle-trained one where trained), and per
``--variant NAME=DIR`` the files ``DIR/seed<k>/ablation_<sweep>.json`` of policies retrained
another way. Flies nothing. Writes ``results/perception_value.json`` (per sweep: per seed the
paired value of perception and perception's share of the gain over PD, across seeds their mean,
range and 95 % t-interval, the pooled episode-level interval, the paper's zeroing share beside;
per variant the same and its change against the base seeds; per wind level what the estimate is
worth to the wind feed-forward laws, from ``--classical``'s files) and
``docs/figures/perception_value.png``; ``python recipes/report.py`` renders the section
"What the estimate is worth" from them (``quadwind_trl/studies/perception.py``).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from quadwind_trl.manifest import command_line, git_commit, repo_relative, write_json
from quadwind_trl.outputs import hold_for_command
from quadwind_trl.regimes import SWEEPS
from quadwind_trl.studies.perception import analyse_sweep, feedforward_by_wind, perception_value, read_seeds, variant_change


def parse_variant(text: str) -> tuple[str, Path]:
    name, eq, folder = text.partition("=")
    if not eq or not name or not folder:
        raise argparse.ArgumentTypeError(f"--variant {text!r}: expected NAME=DIR (DIR holds seed<k>/ablation_<sweep>.json)")
    return name, Path(folder)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=Path, default=Path("results/seeds"), help="the base recipe's seed folders")
    parser.add_argument("--sweeps", nargs="+", default=list(SWEEPS), choices=list(SWEEPS),
                        help="default: every sweep the seeds flew")
    parser.add_argument("--variant", type=parse_variant, action="append", default=[], metavar="NAME=DIR",
                        help="a policy variant's seed folders (repeatable)")
    parser.add_argument("--classical", type=Path, default=Path("results/classical"),
                        help="the classical controllers' ablation files (ablation_<sweep>.json): what the estimate "
                             "is worth to the wind feed-forward laws, beside the policies' value (skipped where absent)")
    parser.add_argument("--out", type=Path, default=Path("results/perception_value.json"))
    parser.add_argument("--figure", type=Path, default=Path("docs/figures/perception_value.png"))
    parser.add_argument("--resamples", type=int, default=10_000, help="bootstrap resamples per paired interval")
    args = parser.parse_args()
    names = [name for name, _ in args.variant]
    if len(set(names)) < len(names):
        parser.error(f"--variant names must differ; got {', '.join(names)}")
    commit = git_commit()
    hold_for_command(args.out, args.figure, what="perception value", hint="wait for it to finish, or choose another --out")
    sweeps, inputs = {}, {"base": {}}
    for sweep in args.sweeps:
        results, read = read_seeds(args.seeds, sweep)
        if results:
            sweeps[sweep] = analyse_sweep(results, resamples=args.resamples)
            inputs["base"][sweep] = read
            classical_file = args.classical / f"ablation_{sweep}.json"
            if classical_file.exists():
                classical = json.loads(classical_file.read_text())
                sweeps[sweep]["feedforward"] = {
                    "file": repo_relative(classical_file), "git_commit": classical.get("git_commit"),
                    "by_wind": feedforward_by_wind(classical, results, resamples=args.resamples)}
    if not sweeps:
        parser.error(f"no seed<k>/ablation_<sweep>.json under {args.seeds} for the sweeps {', '.join(args.sweeps)}")
    variants = {}
    for name, folder in args.variant:
        inputs[name] = {}
        for sweep in sweeps:
            results, read = read_seeds(folder, sweep)
            if results:
                analysis = analyse_sweep(results, resamples=args.resamples)
                analysis["change_vs_base"] = variant_change(sweeps[sweep], analysis)
                variants.setdefault(name, {"folder": repo_relative(folder), "sweeps": {}})["sweeps"][sweep] = analysis
                inputs[name][sweep] = read
        if name not in variants:
            parser.error(f"--variant {name}={folder}: no seed<k>/ablation_<sweep>.json there for {', '.join(sweeps)}")
    payload = {"command": command_line(sys.argv), "git_commit": commit, "resamples": args.resamples,
               "seed_counts": {sweep: len(a["seeds"]) for sweep, a in sweeps.items()}, "inputs": inputs,
               "sweeps": sweeps, "variants": variants, "figure": repo_relative(args.figure)}
    write_json(args.out, payload)
    perception_value(sweeps, args.figure, variants)
    for sweep, a in sweeps.items():
        row = a["by_wind"]["all"].get("aware_vs_trained_blind")
        if row is not None:
            s = row["across_seeds"]
            print(f"{sweep}: wind-aware vs trained blind, xy, {s['n_seeds']} seeds: {s['mean']:+.1f} % "
                  f"(seeds {s['min']:+.1f} to {s['max']:+.1f}; 95 % t-interval {s['t_low']:+.1f} to {s['t_high']:+.1f})")
    print(f"wrote {args.out} and {args.figure}")


if __name__ == "__main__":
    main()
