"""Every stage of the paper, end to end: datasets -> estimators -> PPO policies -> PD baseline
-> paired ablation -> error budget (full runs only) -> report.

    python recipes/reproduce.py --quick     # toy scale, about 4 minutes on 2 idle cores (scripts/quickstart.sh)
    python recipes/reproduce.py --full      # paper scale: hours; resumable, stage by stage

Each stage is one of the recipes in this folder, run as its own process; a stage whose output
already exists is skipped (``--force STAGE`` reruns it), and the long stages resume from their
last checkpoint when interrupted, so a full reproduction can span several sessions.
``--quick`` writes everything under ``runs/quick/`` (or ``--out DIR``) and never touches the shipped checkpoints,
``results/`` or ``docs/``; ``--full`` writes the shipped artifacts.
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CHECKPOINTS = ROOT / "quadwind_trl" / "checkpoints"


@dataclass(frozen=True)
class Stage:
    name: str
    args: tuple[str, ...]
    output: Path  # the stage is done when this exists


def stages(quick: bool, quick_dir: Path = ROOT / "runs" / "quick") -> list[Stage]:
    if quick:
        q = quick_dir
        data = {r: q / "data" / f"flights_{r}" for r in ("horizontal", "vertical")}
        est = {r: q / f"estimator_{r}.pt" for r in ("horizontal", "vertical")}
        pol = {r: q / f"ppo_{r}" for r in ("horizontal", "vertical")}
        out = [
            *(Stage(f"data-{r}", ("generate_flights.py", "--regime", r, "--quick", "--cases", "4", "--out", str(data[r]),
                                          "--threads", "1", "--no-progress"), data[r])
              for r in data),
            *(Stage(f"estimator-{r}", ("train_estimator.py", "--regime", r, "--data", str(data[r]), "--quick", "--out", str(est[r]),
                                       "--log-dir", str(q / "runs"), "--threads", "1", "--no-progress"), est[r]) for r in data),
            Stage("ppo-horizontal", ("ppo_horizontal.py", "--quick", "--estimator", str(est["horizontal"]), "--out", str(pol["horizontal"]),
                                     "--no-progress"), pol["horizontal"] / "policy.pt"),
            Stage("ppo-vertical", ("ppo_vertical_curriculum.py", "--quick", "--estimator", str(est["vertical"]), "--out",
                                   str(pol["vertical"]), "--no-progress"), pol["vertical"] / "policy.pt"),
            # no separate PD-baseline stage (the ablation flies PD on the same episodes), no oracle
            # controller and no out-of-distribution sweep: a toy run shows the pipeline, not results
            Stage("ablation", ("ablation.py", "--quick", "--sweeps", "horizontal", "vertical", "--controllers", "pd", "blind",
                               "aware", "--policy", str(pol["horizontal"] / "policy.pt"), str(pol["vertical"] / "policy.pt"),
                               "--estimator", str(est["horizontal"]), str(est["vertical"]), "--results", str(q / "results"),
                               "--figures", str(q / "figures")), q / "results" / "ablation_vertical.json"),
            Stage("report", ("report.py", "--toy", "--results", str(q / "results"), "--sections", str(q / "sections"),
                             "--out", str(q / "results.md"), "--runs", str(q)),
                  q / "results.md"),
        ]
        return out
    data = {r: ROOT / "data" / f"flights_{r}" for r in ("horizontal", "vertical")}
    unseen = {r: ROOT / "data" / f"flights_{r}_unseen" for r in data}
    unseen_seed = {"horizontal": "1002", "vertical": "2002"}
    return [
        *(Stage(f"data-{r}", ("generate_flights.py", "--regime", r, "--compile", "--threads", "1", "--resume"), data[r]) for r in data),
        *(Stage(f"data-{r}-unseen", ("generate_flights.py", "--regime", r, "--cases", "150", "--seed", unseen_seed[r],
                                     "--out", str(unseen[r]), "--compile", "--threads", "1", "--resume"), unseen[r]) for r in data),
        *(Stage(f"estimator-{r}", ("train_estimator.py", "--regime", r, "--data", str(data[r]), "--threads", "1", "--resume",
                                   "--no-progress"), CHECKPOINTS / f"estimator_{r}.pt") for r in data),
        *(Stage(f"estimator-{r}-evaluation", ("evaluate_estimator.py", "--regime", r, "--data", str(data[r]), "--unseen-data",
                                              str(unseen[r]), "--threads", "1"),
                ROOT / "results" / f"estimation_{r}.json") for r in data),
        Stage("ppo-horizontal", ("ppo_horizontal.py", "--out", "runs/ppo_horizontal", "--resume", "--no-progress"),
              CHECKPOINTS / "policy_horizontal.pt"),
        Stage("ppo-vertical", ("ppo_vertical_curriculum.py", "--out", "runs/ppo_vertical", "--resume", "--no-progress"),
              CHECKPOINTS / "policy_vertical.pt"),
        Stage("pd-baseline", ("pd_baseline.py",), ROOT / "results" / "pd_baseline.json"),
        Stage("ablation", ("ablation.py",), ROOT / "results" / "ablation_ood.json"),
        *(Stage(f"error-budget-{s}", ("error_budget.py", "--sweep", s), ROOT / "results" / f"error_budget_{s}.json")
          for s in ("horizontal", "vertical")),
        Stage("report", ("report.py",), ROOT / "docs" / "results.md"),
    ]


def ship_policy(regime: str) -> None:
    """Copy a finished full-scale PPO run's policy (and manifest) into the package."""
    run = ROOT / "runs" / f"ppo_{regime}"
    for suffix in (".pt", ".json"):
        src = run / f"policy{suffix}"
        if src.exists():
            shutil.copyfile(src, CHECKPOINTS / f"policy_{regime}{suffix}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    scale = parser.add_mutually_exclusive_group(required=True)
    scale.add_argument("--quick", action="store_true")
    scale.add_argument("--full", action="store_true")
    parser.add_argument("--force", nargs="*", default=[], help="stages to rerun even if their output exists ('all' for every stage)")
    parser.add_argument("--only", nargs="*", default=None, help="run only these stages")
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "quick", help="--quick: where everything goes (default runs/quick)")
    args = parser.parse_args()

    plan = stages(args.quick, args.out.resolve())
    names = [s.name for s in plan]
    for name in (args.only or []) + [f for f in args.force if f != "all"]:
        if name not in names:
            parser.error(f"unknown stage {name!r}; stages: {', '.join(names)}")
    start = time.perf_counter()
    for stage in plan:
        if args.only is not None and stage.name not in args.only:
            continue
        forced = "all" in args.force or stage.name in args.force
        if stage.output.exists() and not forced and stage.name != "report":
            print(f"[{stage.name}] done already ({stage.output}); skipping", flush=True)
            continue
        cmd = [sys.executable, str(ROOT / "recipes" / stage.args[0]), *stage.args[1:]]
        if forced and "--overwrite" not in cmd and stage.args[0] in ("generate_flights.py", "train_estimator.py"):
            cmd.append("--overwrite")
        print(f"[{stage.name}] {' '.join(cmd[1:])}", flush=True)
        t0 = time.perf_counter()
        subprocess.run(cmd, cwd=ROOT, check=True)
        if args.full and stage.name.startswith("ppo-"):
            ship_policy(stage.name.split("-")[1])
        print(f"[{stage.name}] finished in {time.perf_counter() - t0:.0f} s", flush=True)
    elapsed = time.perf_counter() - start
    print(f"all stages finished in {elapsed:.0f} s ({elapsed / 60:.1f} min)")
    if args.quick:
        print(toy_summary(args.out.resolve()))


def toy_summary(q: Path) -> str:
    """What the toy run made, its key numbers and the files to open."""
    lines = ["", "Toy run summary (numbers at this scale say nothing about the method; docs/results.md has the paper-scale ones):"]
    for regime in ("horizontal", "vertical"):
        est = q / f"estimator_{regime}.json"
        if est.exists():
            m = json.loads(est.read_text()).get("metrics", {})
            if "per_window_vector_rmse" in m:
                lines.append(f"  {regime} wind estimator: per-window wind RMSE {m['per_window_vector_rmse']:.2f} m/s")
    for sweep in ("horizontal", "vertical", "ood"):
        path = q / "results" / f"ablation_{sweep}.json"
        if path.exists():
            block = json.loads(path.read_text())["rmse_xy"]
            a, d = block["aware"], block["distribution"]
            lines.append(f"  {sweep} sweep, {a['n']} episodes: PD xy RMSE {d['pd']['mean']:.2f} m, wind-aware RL "
                         f"{d['aware']['mean']:.2f} m, RMSE reduction {a['improvement']:+.1f} % (positive = RL better)")
    lines.append("Open:")
    lines.append(f"  {_shown(q / 'results.md')}   the toy report")
    figures = sorted((q / "figures").glob("*.png"))
    if figures:
        lines.append(f"  {_shown(q / 'figures')}/   {len(figures)} figures ({', '.join(f.name for f in figures[:4])}{', ...' if len(figures) > 4 else ''})")
    lines.append(f"  {_shown(q)}/ppo_*/logs   PPO training logs (CSV)")
    return "\n".join(lines)


def _shown(path: Path) -> str:
    """``path`` relative to the repository when inside it (what a user can paste from the root)."""
    try:
        return str(path.relative_to(ROOT))
    except ValueError:
        return str(path)


if __name__ == "__main__":
    main()
