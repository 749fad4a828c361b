"""Recipe candidates x seeds: a PPO run for each, all at once as far as the executor allows, then
one row per candidate of its kept policies' validation results over the seeds.

    python recipes/recipe_sweep.py --regime horizontal --candidates paper lr-decay --seeds 0 1 2
    python recipes/recipe_sweep.py --regime horizontal --executor ray --address auto   # on a Ray cluster
    python recipes/recipe_sweep.py --regime horizontal --quick --seeds 0 1             # toy scale, minutes

Each run is a stage of its own (``quadwind_trl.pipeline.sweep``): the local executor runs ``--jobs``
of them at a time, ``--executor ray`` hands them all to Ray (docs/scaling.md). A run whose policy
exists is skipped, an interrupted one resumes (``--resume``), and the table is rewritten from
every run's kept policy at the end: ``results/recipe_sweep_<regime>.json`` and ``.md`` (``--quick``:
under ``--out``), the rows docs/rl.md's "Choosing the training recipe" compares. The runs keep
their policies by the validation rule, so the table holds validation flights only.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from quadwind_trl.outputs import hold_for_command
from quadwind_trl.pipeline import Stage
from quadwind_trl.pipeline.run import add_executor_arguments, check_executor_arguments, run_plan
from quadwind_trl.pipeline.sweep import CANDIDATES, sweep_runs, sweep_stages

ROOT = Path(__file__).resolve().parent.parent
PPO_RECIPES = {"horizontal": "ppo_horizontal.py", "vertical": "ppo_vertical_curriculum.py"}
DEFAULT_SEEDS = (0, 1, 2)  # three seeds per candidate, as the recipe was chosen


def stage_command(stage: Stage) -> list[str]:
    return [str(ROOT / "recipes" / stage.args[0]), *stage.args[1:]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--regime", required=True, choices=list(PPO_RECIPES))
    described = "; ".join(f"{name}: {' '.join(options)}" for name, options in CANDIDATES.items())
    parser.add_argument("--candidates", nargs="+", default=list(CANDIDATES), choices=list(CANDIDATES),
                        help=f"the recipes compared (default: all): {described}")
    parser.add_argument("--seeds", nargs="+", type=int, default=list(DEFAULT_SEEDS))
    parser.add_argument("--quick", action="store_true", help="toy PPO runs (the recipes' --quick): the table shows the sweep runs")
    parser.add_argument("--out", type=Path, default=None,
                        help="where the runs go (default runs/recipe_sweep_<regime>[_quick]); --quick: the table too")
    parser.add_argument("--force", nargs="*", default=[], help="runs to redo even if their policy exists ('all': every one)")
    add_executor_arguments(parser)
    args = parser.parse_args()
    check_executor_arguments(parser, args)
    runs_dir = (args.out or ROOT / "runs" / f"recipe_sweep_{args.regime}{'_quick' if args.quick else ''}").resolve()
    table = (runs_dir if args.quick else ROOT / "results") / f"recipe_sweep_{args.regime}.json"
    try:
        runs = sweep_runs(args.candidates, args.seeds, runs_dir)
    except ValueError as err:
        parser.error(str(err))
    names = [r.stage for r in runs]
    for name in args.force:
        if name != "all" and name not in names:
            parser.error(f"--force {name}: not a run of this sweep; runs: {', '.join(names)}")
    times = runs_dir / "pipeline_times.json"
    hold_for_command(times, what="sweep record", hint="wait for that sweep to finish, or choose another --out")
    plan = sweep_stages(runs, PPO_RECIPES[args.regime], ("--quick",) if args.quick else (), table)
    run_plan(parser, args, plan, plan, times, stage_command, ROOT)
    print(table.with_suffix(".md").read_text(), end="")
    print(f"rows: {table} (and .md); per-run wall times: {times}")


if __name__ == "__main__":
    main()
