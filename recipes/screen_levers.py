"""Screen the learning levers on validation flights: for each named lever setting x seed, train
the residual on a classical base (default: the disturbance observer) for a given number of
decisions, fly the kept policy and the base alone on the regime's validation sweep (the same
episodes, paired), and write one JSON row per run plus a markdown table.

    python recipes/screen_levers.py --levers residual base_state privileged_critic memory4 combined \\
        --seeds 0 1 2 --frames 500000
    python recipes/screen_levers.py --levers residual "mem8=--memory-frames 8" --seeds 0 1 2 --frames 500000
    python recipes/screen_levers.py --quick --untrained-estimator --levers residual memory4 --seeds 0   # smoke

Lever settings: the names of ``quadwind_trl.rl.screening.LEVERS`` (``--list`` prints them with
their flags) or ``NAME=FLAGS``, the PPO recipes' own flags. Every run is the PPO recipe with
those flags (``recipes/ppo_horizontal.py``; ``--regime vertical``: the curriculum recipe), its
checkpoints and logs under ``--runs`` (default ``runs/screen_levers``, never committed). Flags this
recipe does not know are given to every run (e.g. ``--threads 1 --eval-every 131072``).

Writes ``OUT/rows/<lever>_seed<k>.json`` as each run finishes, and ``OUT/screen.json`` (rows and
the per-lever summary) and ``OUT/screen.md`` at the end (default OUT:
``results/experiments/levers/<regime>_<base>``). A run whose row is on disk is not trained again,
so an interrupted screen resumes where it stopped (an interrupted run from its checkpoint). Only
validation flights are flown: choosing among the levers never looks at a test sweep.

Seeds run beside each other each need an ``--out`` of their own (a screen holds its folder);
``--collect DIR [DIR ...]`` then gathers their rows into ``--out`` as one screen, training nothing:

    python recipes/screen_levers.py --collect runs/out/seed0 runs/out/seed1 --out results/experiments/levers/x
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import asdict
from pathlib import Path

from quadwind_trl.manifest import command_line, git_commit, platform_info, repo_relative, write_json
from quadwind_trl.outputs import hold_for_command
from quadwind_trl.regimes import CLASSICAL_CONTROLLERS
from quadwind_trl.rl.screening import LEVERS, ScreenMismatch, ScreenPlan, collect, parse_lever, screen, summarize, table


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--regime", default="horizontal", choices=["horizontal", "vertical"])
    p.add_argument("--base", default="dob", choices=CLASSICAL_CONTROLLERS, help="the classical base (default dob)")
    p.add_argument("--levers", nargs="+", default=["residual"], metavar="NAME|NAME=FLAGS",
                   help="lever settings: names of the catalogue (--list) or NAME=FLAGS (PPO recipe flags)")
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    p.add_argument("--frames", type=int, default=None, help="decisions each run trains for (default 500,000; --quick: 1,024)")
    p.add_argument("--val-episodes", type=int, default=None,
                   help="validation episodes each run is scored on, an even spread (default: the whole sweep; --quick: 2)")
    p.add_argument("--out", type=Path, default=None, help="default results/experiments/levers/<regime>_<base>[_quick]")
    p.add_argument("--runs", type=Path, default=Path("runs/screen_levers"), help="the training runs' folder")
    p.add_argument("--quick", action="store_true", help="the recipes' --quick runs on their short flights (smoke test)")
    p.add_argument("--resamples", type=int, default=10_000, help="bootstrap resamples of each paired interval")
    p.add_argument("--list", action="store_true", help="print the catalogue of lever settings and exit")
    p.add_argument("--collect", nargs="+", type=Path, default=None, metavar="DIR",
                   help="gather the rows of these screens' output folders into --out as one screen (trains nothing)")
    args, extra = p.parse_known_args()
    # the code's commit, taken before this recipe writes anything: rewriting rows that are
    # committed under OUT must not mark the record "-dirty"
    commit = git_commit()
    if args.list:
        for name, flags in LEVERS[args.regime].items():
            print(f"{name:20s} {' '.join(flags) or '(the recipe as it is)'}")
        return
    if args.collect:
        if args.out is None:
            p.error("--collect writes the gathered screen to --out: name it")
        return _collect(args.collect, args.out, commit)
    try:
        plan = ScreenPlan(
            regime=args.regime, base=args.base, levers=tuple(parse_lever(t, args.regime) for t in args.levers),
            seeds=tuple(args.seeds), frames=args.frames if args.frames is not None else (1_024 if args.quick else 500_000),
            out=args.out or Path(f"results/experiments/levers/{args.regime}_{args.base}{'_quick' if args.quick else ''}"),
            runs=args.runs, val_episodes=args.val_episodes if args.val_episodes is not None else (2 if args.quick else None),
            extra_flags=tuple(extra), quick=args.quick, resamples=args.resamples)
    except ValueError as err:
        raise SystemExit(f"error: {err}") from None
    hold_for_command(plan.out, what="lever screen", hint="wait for it to finish, or choose another --out")
    try:
        rows = screen(plan)
    except ScreenMismatch as err:
        raise SystemExit(f"error: {err}") from None
    command = command_line(sys.argv)
    _write(plan.out, rows, [command], commit, {"plan": {k: (repo_relative(v) if isinstance(v, Path) else v)
                                                for k, v in asdict(plan).items()}})


def _write(out: Path, rows: list, commands: list[str], commit: str | None, extra: dict) -> None:
    """``out/screen.json`` (rows, summary, the commands that flew them, the commit the recipe ran
    at) and ``out/screen.md``."""
    regime, base = rows[0].regime, rows[0].base
    write_json(out / "screen.json", {"command": commands[-1], "commands": commands, "git_commit": commit,
                                     "platform": platform_info(), **extra, "summary": summarize(rows),
                                     "rows": [asdict(r) for r in rows]})
    flown_at = sorted({r.git_commit or "unknown" for r in rows})
    md = (f"Lever screen, {regime} validation sweep, residual on `{base}`: gain = RMSE reduction of the residual over "
          f"{base} alone on the same episodes (positive = better), 95 % paired bootstrap interval. Flown at "
          f"{', '.join(f'`{c[:7]}`' for c in flown_at)} by:\n\n" + "".join(f"`{c}`\n\n" for c in commands)
          + table(rows, base))
    (out / "screen.md").write_text(md)
    print(md)


def _collect(folders: list[Path], out: Path, commit: str | None) -> None:
    """``--collect``: the rows of ``folders`` gathered into ``out`` as one screen."""
    try:
        rows, commands = collect(folders)
    except ValueError as err:
        raise SystemExit(f"error: {err}") from None
    rows.sort(key=lambda r: (r.lever, r.seed))
    for row in rows:
        write_json(out / "rows" / f"{row.lever}_seed{row.seed}.json", asdict(row))
    _write(out, rows, [*commands, command_line(sys.argv)], commit, {"collected_from": [repo_relative(f) for f in folders]})


if __name__ == "__main__":
    main()
