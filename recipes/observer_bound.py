"""How much better the best classical base could cancel the wind (``quadwind_trl/studies/observer_bound.py``):
the stiffer-inner-loop disturbance observer flown again on a regime's validation sweep with its
filter off, a perfect accelerometer, the true state, the wind off and a wider tilt limit, each paired against the
law as chosen on the same episodes. No training: the ceiling of reactive wind information a
learned residual is measured against.

    python recipes/observer_bound.py                                # both regimes
    python recipes/observer_bound.py --regimes horizontal
    python recipes/observer_bound.py --quick                        # three episodes, short flights

Writes ``RESULTS/observer_bound_<regime>.json`` (every variant's RMSEs and paired gains, the
command, commit and platform) and ``RESULTS/observer_bound.md`` (the tables); RESULTS is
``results/experiments/observer_bound`` (``--quick``: ``runs/quick/observer_bound``).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

from quadwind_trl.config import config_to_dict
from quadwind_trl.manifest import command_line, git_commit, platform_info, write_json
from quadwind_trl.outputs import hold_for_command
from quadwind_trl.studies.base_search import validation_setup
from quadwind_trl.studies.observer_bound import BASE, bound_rows, bound_table, episode_rows, fly_variants, regime_markdown


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--regimes", nargs="+", default=["horizontal", "vertical"], choices=["horizontal", "vertical"])
    parser.add_argument("--quick", action="store_true", help="three validation episodes, 10 s patterns")
    parser.add_argument("--results", type=Path, default=None,
                        help="output folder (default results/experiments/observer_bound; --quick: runs/quick/observer_bound)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--compile", action=argparse.BooleanOptionalAction, default=None,
                        help="the compiled simulator step (default: as the regime's shipped policy trained; --quick: eager)")
    args = parser.parse_args()
    results = args.results or Path("runs/quick/observer_bound" if args.quick else "results/experiments/observer_bound")
    outputs = [results / f"observer_bound_{regime}.json" for regime in args.regimes]
    hold_for_command(*outputs, results / "observer_bound.md", what="observer-bound results",
                     hint="wait for it to finish, or choose another --results")
    torch.set_num_threads(args.threads)
    commit = git_commit()  # before this run writes its (tracked) outputs
    for regime, out in zip(args.regimes, outputs):
        # the env the regime's policies train and are screened in (its sensing, flights and estimate)
        config, scenarios, compile_step, _ = validation_setup(regime, args.quick, args.compile)
        start = time.perf_counter()
        flown = fly_variants(regime, scenarios, config, compile_step=compile_step, progress=not args.quick)
        rows = bound_rows(flown)
        wall = time.perf_counter() - start
        write_json(out, {"command": command_line(sys.argv), "git_commit": commit, "platform": platform_info(),
                         "regime": regime, "base": BASE, "episodes": scenarios.batch_size[0], "compile_step": compile_step,
                         "config": config_to_dict(config), "wall_time_s": round(wall, 1), "variants": rows,
                         "per_episode": episode_rows(scenarios, flown)})
        print(f"{regime}: {BASE} on {scenarios.batch_size[0]} validation episodes ({wall:.0f} s)\n{bound_table(rows)}")
    write_markdown(results)


def write_markdown(results: Path) -> None:
    """``observer_bound.md``: every regime file in ``results``, as the results page shows them."""
    parts = ["# The observer's bound on validation", ""]
    for path in sorted(results.glob("observer_bound_*.json")):
        parts += regime_markdown(json.loads(path.read_text()), path.name)
    (results / "observer_bound.md").write_text("\n".join(parts))


if __name__ == "__main__":
    main()
