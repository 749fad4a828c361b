"""Every stage of the paper, end to end: datasets -> estimators -> PPO policies -> PD baseline
-> paired ablation -> classical controllers and error budget (full runs only) -> report.

    python recipes/reproduce.py --quick     # toy scale, about 2 minutes on 2 cores (scripts/quickstart.sh)
    python recipes/reproduce.py --full      # paper scale: hours; resumable, stage by stage
    python recipes/reproduce.py --full --only ppo-horizontal-seed1 ppo-vertical-seed1

Each stage is one of the recipes in this folder, run as its own single-threaded process (forked
from a server that has imported torch, TorchRL and the library once); up to
``--jobs`` (default 2) run at once, each as soon as the stages whose outputs it reads have finished
(the horizontal and the vertical chains side by side; each line of output is prefixed with its
stage's name). A stage whose output already exists is skipped (``--force STAGE`` reruns it), and
the long stages resume from their last checkpoint when interrupted, so a full reproduction can
span several sessions. Each finished stage's wall time, commit and machine load are added to
``pipeline_times.json`` (``results/``); with two stages at once each one's wall time is that of a
shared machine (its load is recorded beside it).
``--executor ray`` runs each stage as a Ray task instead, on a local Ray instance of ``--jobs``
CPUs or, with ``--address auto|HOST:PORT``, on a running Ray cluster (docs/scaling.md); the
same stages, outputs, skipping and record, each stage's node included.
``--quick`` writes everything under ``runs/quick/`` (or ``--out DIR``) and never touches the shipped checkpoints,
``results/`` or ``docs/``; ``--full`` writes the shipped artifacts.

``--full`` trains each regime's policy with five seeds (:data:`SEEDS`), wind-aware and trained
blind (:data:`POLICY_KINDS`), and three oracle-trained horizontal ones (:data:`ORACLE_SEEDS`),
keeps every seed's policy in ``results/policies/``, flies every seed's paired ablation
(``results/seeds/seed<k>/``), measures what the estimate is worth across them
(``perception-value``), tunes and flies the classical controllers (``base-search``,
``classical-<regime>``), trains the residual on the best of them with three seeds
(:data:`RESIDUAL_BASE`, :data:`RESIDUAL_SEEDS`) and measures it against that base and PD
(``results/residual/<base>/seed<k>/``, ``residual-<base>-value``), then ships the median seed of each
(``ship-policies``: ``quadwind_trl/checkpoints/policy_<regime>[_trained_blind].pt``, and its
ablations as ``results/ablation_<sweep>.json``).
"""
from __future__ import annotations

import argparse
import json
import shutil
import time
from functools import partial
from pathlib import Path

from quadwind_trl.manifest import repo_relative
from quadwind_trl.outputs import hold_for_command
from quadwind_trl.pipeline import Stage, is_forced, longest_chain
from quadwind_trl.pipeline.run import add_executor_arguments, check_executor_arguments, run_plan

ROOT = Path(__file__).resolve().parent.parent
CHECKPOINTS = ROOT / "quadwind_trl" / "checkpoints"


def stages(quick: bool, quick_dir: Path = ROOT / "runs" / "quick") -> list[Stage]:
    if quick:
        q = quick_dir
        data = {r: q / "data" / f"flights_{r}" for r in ("horizontal", "vertical")}
        est = {r: q / f"estimator_{r}.pt" for r in ("horizontal", "vertical")}
        pol = {r: q / f"ppo_{r}" for r in ("horizontal", "vertical")}
        # --resume as at full scale: a stage restarted (a Ray retry) goes on from its last checkpoint
        out = [
            *(Stage(f"data-{r}", ("generate_flights.py", "--regime", r, "--quick", "--cases", "4", "--out", str(data[r]),
                                          "--threads", "1", "--resume", "--no-progress"), data[r], needs=())
              for r in data),
            *(Stage(f"estimator-{r}", ("train_estimator.py", "--regime", r, "--data", str(data[r]), "--quick", "--out", str(est[r]),
                                       "--log-dir", str(q / "runs"), "--threads", "1", "--resume", "--no-progress"), est[r],
                    needs=(f"data-{r}",)) for r in data),
            *(Stage(f"ppo-{r}", (PPO_RECIPES[r], "--quick", "--estimator", str(est[r]), "--out", str(pol[r]), "--resume",
                                 "--no-progress"),
                    pol[r] / "policy.pt", needs=(f"estimator-{r}",)) for r in data),
            # no separate PD-baseline stage (the ablation flies PD on the same episodes), no oracle
            # controller and no out-of-distribution sweep: a toy run shows the pipeline, not results
            *(Stage(f"ablation-{r}", ("ablation.py", "--quick", "--sweeps", r, "--controllers", "pd", "blind", "aware",
                                      "--policy", str(pol[r] / "policy.pt"), "--estimator", str(est[r]), "--results",
                                      str(q / "results"), "--figures", str(q / "figures")),
                    q / "results" / f"ablation_{r}.json", needs=(f"ppo-{r}",)) for r in data),
            Stage("report", ("report.py", "--toy", "--results", str(q / "results"), "--sections", str(q / "sections"),
                             "--out", str(q / "results.md"), "--runs", str(q)),
                  q / "results.md", rerun=True),
        ]
        return out
    # only the full plan names the classical controllers: a toy run's driving process then imports
    # no torch (3 s of CPU, while the stage server and the first flight import it beside)
    from quadwind_trl.regimes import CLASSICAL_CONTROLLERS

    data = {r: ROOT / "data" / f"flights_{r}" for r in REGIMES}
    unseen = {r: ROOT / "data" / f"flights_{r}_unseen" for r in data}
    unseen_seed = {"horizontal": "1002", "vertical": "2002"}
    plan = [
        *(Stage(f"data-{r}", ("generate_flights.py", "--regime", r, "--compile", "--threads", "1", "--resume"), data[r], needs=())
          for r in data),
        *(Stage(f"data-{r}-unseen", ("generate_flights.py", "--regime", r, "--cases", "150", "--seed", unseen_seed[r],
                                     "--out", str(unseen[r]), "--compile", "--threads", "1", "--resume"), unseen[r], needs=())
          for r in data),
        *(Stage(f"estimator-{r}", ("train_estimator.py", "--regime", r, "--data", str(data[r]), "--threads", "1", "--resume",
                                   "--no-progress"), CHECKPOINTS / f"estimator_{r}.pt", needs=(f"data-{r}",)) for r in data),
        # --update-checkpoint records the validation-best EMA tau, which the policies then train with
        *(Stage(f"estimator-{r}-evaluation", ("evaluate_estimator.py", "--regime", r, "--data", str(data[r]), "--unseen-data",
                                              str(unseen[r]), "--threads", "1", "--update-checkpoint"),
                ROOT / "results" / f"estimation_{r}.json", needs=(f"estimator-{r}", f"data-{r}-unseen")) for r in data),
    ]
    trained = [(r, kind, seed) for kind in POLICY_KINDS for seed in SEEDS for r in REGIMES]
    trained += [("horizontal", ORACLE_KIND, seed) for seed in ORACLE_SEEDS]
    trained += [(r, kind, seed) for kind in RESIDUAL_KINDS for seed in RESIDUAL_SEEDS for r in REGIMES]
    for r, kind, seed in trained:
        run = policy_run(r, kind, seed)
        plan.append(Stage(_stage_name(run), (PPO_RECIPES[r], "--out", str(run), "--seed", str(seed), *TRAINING_OPTIONS[kind],
                                             "--resume", "--no-progress"), kept_policy(r, kind, seed),
                          after=partial(keep_policy, r, kind, seed), needs=(f"estimator-{r}-evaluation",)))
    for seed in SEEDS:
        # each seed's wind-aware and trained-blind (and oracle-trained) policies on all three
        # sweeps, every controller; per regime, so a seed's horizontal flights need no vertical policy
        out = SEED_RESULTS / f"seed{seed}"
        for r, sweeps in REGIME_SWEEPS:
            kinds = (*POLICY_KINDS, *((ORACLE_KIND,) if r == "horizontal" and seed in ORACLE_SEEDS else ()))
            oracle = ("--oracle-policy", str(kept_policy(r, ORACLE_KIND, seed))) if ORACLE_KIND in kinds else ()
            plan.append(Stage(f"ablation-seed{seed}-{r}", ("ablation.py", "--sweeps", *sweeps, "--policy", str(kept_policy(r, "aware", seed)),
                                                           "--blind-policy", str(kept_policy(r, "trained_blind", seed)), *oracle,
                                                           "--results", str(out), "--figures", str(out / "figures")),
                              out / f"ablation_{sweeps[-1]}.json",
                              needs=tuple(_stage_name(policy_run(r, kind, seed)) for kind in kinds)))
    # the classical controllers, once per sweep (they fly no policy: no seed changes them), with the
    # constants their validation search chose (regimes.CLASSICAL_CHOICES holds the values it wrote)
    plan.append(Stage("base-search", ("tune_base_controllers.py",), ROOT / "results" / "base_search_vertical.json"))
    for r, sweeps in REGIME_SWEEPS:
        plan.append(Stage(f"classical-{r}", ("ablation.py", "--sweeps", *sweeps, "--controllers", "pd", *CLASSICAL_CONTROLLERS,
                                             "--results", str(ROOT / "results" / "classical")),
                          ROOT / "results" / "classical" / f"ablation_{sweeps[-1]}.json", needs=("base-search",)))
    # the residual on that base, per seed the zero residual (the base alone) and both residuals on
    # every sweep, then every seed against the base alone and PD (the classical files fly both)
    aware, blind = RESIDUAL_KINDS
    residual = []
    for seed in RESIDUAL_SEEDS:
        out = RESIDUAL_RESULTS / f"seed{seed}"
        for r, sweeps in REGIME_SWEEPS:
            residual.append(Stage(f"residual-{RESIDUAL_BASE}-seed{seed}-{r}", (
                "ablation.py", "--sweeps", *sweeps, "--controllers", "pd", "aware", "trained_blind",
                "--policy", str(kept_policy(r, aware, seed)), "--blind-policy", str(kept_policy(r, blind, seed)),
                "--results", str(out), "--figures", str(out / "figures")), out / f"ablation_{sweeps[-1]}.json",
                needs=tuple(_stage_name(policy_run(r, kind, seed)) for kind in RESIDUAL_KINDS)))
    plan += residual
    plan.append(Stage(f"residual-{RESIDUAL_BASE}-value", ("residual_value.py", "--base", RESIDUAL_BASE),
                      ROOT / "results" / f"residual_{RESIDUAL_BASE}.json",
                      needs=(*(stage.name for stage in residual), *(f"classical-{r}" for r in REGIMES))))
    plan += [
        Stage("perception-value", ("perception_value.py",), ROOT / "results" / "perception_value.json"),
        Stage("ship-policies", (), CHECKPOINTS / "policy_vertical_trained_blind.pt", after=ship_median_seeds),
        Stage("pd-baseline", ("pd_baseline.py",), ROOT / "results" / "pd_baseline.json"),
        *(Stage(f"error-budget-{s}", ("error_budget.py", "--sweep", s), ROOT / "results" / f"error_budget_{s}.json")
          for s in ("horizontal", "vertical")),
        Stage("report", ("report.py",), ROOT / "docs" / "results.md", rerun=True),
    ]
    return plan


REGIMES = ("horizontal", "vertical")
PPO_RECIPES = {"horizontal": "ppo_horizontal.py", "vertical": "ppo_vertical_curriculum.py"}
SEEDS = (0, 1, 2, 3, 4)  # five per regime and kind: the shipped one is the median by validation
# the policies trained per regime and seed, with their recipe options: the paper's wind-aware
# policy, and one trained from scratch with its wind inputs zeroed (the perception baseline)
POLICY_KINDS = {"aware": (), "trained_blind": ("--wind-input", "zero")}
# the policy trained on the true mean wind (what a perfect estimate is worth to a policy
# trained with it, against the trained-blind one); three seeds, horizontal, never shipped
ORACLE_KIND, ORACLE_SEEDS = "trained_oracle", (0, 1, 2)
# the residual re-based on the classical controller with the best validation score in both regimes
# (docs/results.md, "Against classical controllers"), three seeds per regime, wind-aware and
# trained blind, the shipped recipe otherwise; never shipped
RESIDUAL_BASE, RESIDUAL_SEEDS = "dob", (0, 1, 2)
RESIDUAL_KINDS = {f"residual_{RESIDUAL_BASE}": ("--base-controller", RESIDUAL_BASE),
                  f"residual_{RESIDUAL_BASE}_trained_blind": ("--base-controller", RESIDUAL_BASE, "--wind-input", "zero")}
RESIDUAL_RESULTS = ROOT / "results" / "residual" / RESIDUAL_BASE
TRAINING_OPTIONS = POLICY_KINDS | {ORACLE_KIND: ("--wind-input", "truth")} | RESIDUAL_KINDS
# the sweeps each regime's policies fly
REGIME_SWEEPS = (("horizontal", ("horizontal", "ood")), ("vertical", ("vertical",)))
# every seed's policy is kept (about 0.6 MB each) so that each seed's ablation can be re-flown
SEED_POLICIES = ROOT / "results" / "policies"
SEED_RESULTS = ROOT / "results" / "seeds"


def policy_run(regime: str, kind: str, seed: int) -> Path:
    suffix = "" if kind == "aware" else f"_{kind}"
    return ROOT / "runs" / f"ppo_{regime}{suffix}_seed{seed}"


def _stage_name(run: Path) -> str:
    """A PPO run's stage, named after its folder (``ppo-horizontal-trained-blind-seed1``)."""
    return run.name.replace("_", "-")


def kept_policy(regime: str, kind: str, seed: int) -> Path:
    return SEED_POLICIES / f"{policy_run(regime, kind, seed).name}.pt"


def _copy_policy(src: Path, dst: Path) -> None:
    """A policy and its JSON manifest."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    for suffix in (".json", ".pt"):  # the .pt last: it marks the copy done
        shutil.copyfile(src.with_suffix(suffix), dst.with_suffix(suffix))


def keep_policy(regime: str, kind: str, seed: int) -> None:
    """Copy a finished PPO run's policy (and manifest) to ``results/policies/``."""
    _copy_policy(policy_run(regime, kind, seed) / "policy.pt", kept_policy(regime, kind, seed))


def median_seed(regime: str, kind: str) -> int:
    """The seed in the middle of the seeds by its kept policy's validation score (its manifest's
    ``selection``: the rule training kept it by, on the regime's validation sweep). The test
    sweeps choose nothing, the shipped seed included."""
    score = {}
    for seed in SEEDS:
        path = kept_policy(regime, kind, seed).with_suffix(".json")
        selection = json.loads(path.read_text()).get("selection", {})
        if "validation_score" not in selection:
            raise ValueError(f"{repo_relative(path)} has no validation score (trained before the validation sweep): "
                             "retrain it to ship by validation")
        score[seed] = selection["validation_score"]
    return sorted(score, key=score.get)[len(SEEDS) // 2]


def ship_median_seeds() -> None:
    """Ship the median seed's policy of each regime and kind (``quadwind_trl/checkpoints/
    policy_<regime>[_trained_blind].pt``), and make the wind-aware median seed's ablations the
    headline results (``results/ablation_<sweep>.json``; they record the kept policy they flew,
    byte for byte the shipped one) with their figures (``docs/figures/``)."""
    from quadwind_trl.evaluation.figures import ABLATION_FIGURES

    for regime in REGIMES:
        for kind in POLICY_KINDS:
            seed = median_seed(regime, kind)
            suffix = "" if kind == "aware" else f"_{kind}"
            _copy_policy(kept_policy(regime, kind, seed), CHECKPOINTS / f"policy_{regime}{suffix}.pt")
            print(f"shipped the {regime} {kind} policy of seed {seed}", flush=True)
    for sweep, regime in (("horizontal", "horizontal"), ("vertical", "vertical"), ("ood", "horizontal")):
        seed = median_seed(regime, "aware")
        shutil.copyfile(SEED_RESULTS / f"seed{seed}" / f"ablation_{sweep}.json", ROOT / "results" / f"ablation_{sweep}.json")
        panels, trace = ABLATION_FIGURES[sweep]
        for name in [name for _, name in panels] + ([trace[-1]] if trace else []):
            shutil.copyfile(SEED_RESULTS / f"seed{seed}" / "figures" / name, ROOT / "docs" / "figures" / name)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    scale = parser.add_mutually_exclusive_group(required=True)
    scale.add_argument("--quick", action="store_true")
    scale.add_argument("--full", action="store_true")
    parser.add_argument("--force", nargs="*", default=[], help="stages to rerun even if their output exists ('all' for every stage)")
    parser.add_argument("--only", nargs="*", default=None, help="run only these stages")
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "quick", help="--quick: where everything goes (default runs/quick)")
    parser.add_argument("--chain", action="store_true",
                        help="print the plan's longest chain of dependent stages by recorded wall time, and run nothing")
    add_executor_arguments(parser)
    args = parser.parse_args()
    check_executor_arguments(parser, args)

    plan = stages(args.quick, args.out.resolve())
    names = [s.name for s in plan]
    for name in (args.only or []) + [f for f in args.force if f != "all"]:
        if name not in names:
            parser.error(f"unknown stage {name!r}; stages: {', '.join(names)}")
    times = (args.out.resolve() if args.quick else ROOT / "results") / "pipeline_times.json"
    if args.chain:
        print(chain_summary(plan, times))
        return
    # one reproduction per record: each stage also locks its own output
    hold_for_command(times, what="reproduction record",
                     hint="wait for that reproduction to finish" + (", or choose another --out" if args.quick else ""))
    start = time.perf_counter()
    selected = [s for s in plan if args.only is None or s.name in args.only]
    run_plan(parser, args, selected, plan, times, partial(stage_command, force=args.force), ROOT)
    elapsed = time.perf_counter() - start
    print(f"this session's stages finished in {elapsed:.0f} s ({elapsed / 60:.1f} min); per stage, over sessions: {times}")
    if args.quick:
        print(toy_summary(args.out.resolve()))


def chain_summary(plan: list[Stage], times: Path) -> str:
    """The longest chain (``--chain``): each stage's recorded time, the total, and the stages
    with no record, which make it a lower bound."""
    record = json.loads(times.read_text()) if times.exists() else {}
    chain = longest_chain(plan, record)
    total = sum(entry.get("wall_time_s", 0.0) for name, entry in record.items() if name in {s.name for s in plan})
    lines = [f"{name}: {'no record' if seconds is None else f'{seconds:.0f} s'}" for name, seconds in chain.stages]
    lines.append(f"longest chain {chain.seconds:.0f} s ({chain.seconds / 3600:.1f} h) of {total:.0f} s recorded over "
                 f"{len(plan) - len(chain.untimed)} of {len(plan)} stages ({times})")
    if chain.untimed:
        lines.append(f"no recorded time (counted as 0 s: the chain is a lower bound): {', '.join(chain.untimed)}")
    return "\n".join(lines)


def stage_command(stage: Stage, force: list[str]) -> list[str]:
    """The recipe ``stage`` runs and its arguments (without the Python that runs it); a forced
    dataset or estimator stage overwrites its output."""
    cmd = [str(ROOT / "recipes" / stage.args[0]), *stage.args[1:]]
    if is_forced(stage, force) and "--overwrite" not in cmd and stage.args[0] in ("generate_flights.py", "train_estimator.py"):
        cmd.append("--overwrite")
    return cmd


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
