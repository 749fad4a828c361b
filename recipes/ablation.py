"""The paired ablation: PD, wind-blind RL, wind-aware RL, a true-wind oracle, a policy trained
without wind inputs and (given one) a policy trained with the true wind, and the classical
controllers (PID, disturbance observer, wind feed-forward with its blind twin and oracle;
``regimes.CLASSICAL_CONTROLLERS``), on identical replayed episodes of the paper's evaluation
sweeps; tables (JSON) and figures.

    python recipes/ablation.py                                   # horizontal 225, vertical 144, OOD 90
    python recipes/ablation.py --sweeps horizontal --policy runs/ppo_horizontal/policy.pt
    python recipes/ablation.py --quick                           # small subsets, short flights
    python recipes/ablation.py --sweeps horizontal --batch 45          # five batches of 45 episodes
    python recipes/ablation.py --sweeps horizontal --oracle-policy runs/ppo_horizontal_truth/policy.pt
    python recipes/ablation.py --verify results/ablation_horizontal.json --chunks 0:1
    python recipes/ablation.py --resummarize results/seeds/seed0/ablation_*.json
    python recipes/ablation.py --controllers pd pid dob pd_ff pd_ff_blind pd_ff_oracle --results results/classical

By default the shipped checkpoints are used (``quadwind_trl/checkpoints/policy_<regime>.pt``,
``policy_<regime>_trained_blind.pt`` and ``estimator_<regime>.pt``); without a trained-blind
policy the ``trained_blind`` controller is left out, and said so; ``trained_oracle`` (a policy
trained with ``--wind-input truth``, none is shipped) flies only with ``--oracle-policy``.
Writes ``results/ablation_<sweep>.json`` and ``docs/figures/*.png`` (``--quick``: under
``runs/quick/``); ``python recipes/report.py`` renders them into docs/results.md. ``--batch B`` flies B episodes at a time (default: the whole sweep in one batch,
the fastest), recorded in the file. ``--verify FILE`` writes nothing: it re-flies batches
``--chunks A:B`` of a results file exactly as the file records them (sweep, controllers, policy,
estimator, flights, simulator, batch layout) and reports, per controller, against the
reproducibility contract (docs/simulator.md, "Exact replay"): "bitwise (same platform)" on the
platform the file records, else the distribution of the deviations and whether they stay within
the cross-platform tolerance (where one was measured: quick horizontal flights) or are
equivalent to the record within a stated margin (any other: the mean paired difference and its
interval, per controller); exit
status 1 where the contract does not hold. A batch is the unit because only the recorded layout
replays bit for bit (``evaluation.replay.verify_ablation``). ``--resummarize
FILE...`` flies nothing: it recomputes a file's tables from its own per-episode table with the
current summary code (kept: the flight's command and commit; added: ``summarized_by``) and says
which tables it added or changed.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

from quadwind_trl.config import MonitorConfig, config_to_dict
from quadwind_trl.evaluation import figures
from quadwind_trl.evaluation.ablation import (CONTROLLERS, RL_CONTROLLERS, TRAINED_POLICY_KEYS, episode_table, episode_table_from_json,
                                              fly_controllers, policy_compile_step, policy_env_config, summarize_ablation)
from quadwind_trl.evaluation.phases import pattern_starts
from quadwind_trl.evaluation.replay import CROSS_PLATFORM_RTOL, flown_quick, replay_verdict, verify_ablation
from quadwind_trl.evaluation.tracking import sweep_setup
from quadwind_trl.manifest import command_line, git_commit, platform_info, repo_relative, write_json
from quadwind_trl.estimator import load_estimator
from quadwind_trl.manifest import CHECKPOINT_DIR
from quadwind_trl.outputs import hold_for_command
from quadwind_trl.rl.policy import load_policy
from quadwind_trl.regimes import SWEEP_REGIME, SWEEPS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sweeps", nargs="+", default=list(SWEEPS), choices=list(SWEEPS))
    parser.add_argument("--policy", type=Path, nargs="*", default=None,
                        help="policy checkpoints, one per regime in the order horizontal, vertical (default: shipped)")
    parser.add_argument("--estimator", type=Path, nargs="*", default=None,
                        help="estimator checkpoints, same order, or 'ukf' (the model-based filter, horizontal only)")
    parser.add_argument("--blind-policy", type=Path, nargs="*", default=None,
                        help="policies trained with --wind-input zero, same order (default: shipped, if any)")
    parser.add_argument("--oracle-policy", type=Path, nargs="*", default=None,
                        help="policies trained with --wind-input truth, same order (default: none, and no trained_oracle)")
    parser.add_argument("--controllers", nargs="+", default=None, choices=list(CONTROLLERS),
                        help=f"default: {' '.join(RL_CONTROLLERS)} (trained_blind only where a trained-blind policy exists, "
                             "trained_oracle only with --oracle-policy); the classical controllers fly when named "
                             "(they depend on no policy: recipes/reproduce.py flies them once per sweep)")
    parser.add_argument("--quick", action="store_true", help="one seed and intensity per sweep, 10 s patterns flown from their start")
    parser.add_argument("--results", type=Path, default=None, help="results directory (default results/, --quick runs/quick/results)")
    parser.add_argument("--figures", type=Path, default=None, help="figure directory (default docs/figures, --quick runs/quick/figures)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--batch", type=int, default=None, help="episodes flown at once (default: the whole sweep)")
    parser.add_argument("--verify", type=Path, default=None, help="re-fly --chunks of this results file and compare")
    parser.add_argument("--chunks", default=None, help="with --verify: batches START:STOP of the file's layout (default all)")
    parser.add_argument("--resummarize", type=Path, nargs="+", default=None,
                        help="recompute these results files' tables from their episode tables (flies nothing)")
    parser.add_argument("--monitor", action="store_true",
                        help="fly every policy with the runtime monitor (MonitorConfig defaults; docs/rl.md, \"Runtime monitor\"): "
                             "a deployment option reported beside the raw policy, never a choice")
    parser.add_argument("--eager", action="store_true",
                        help="fly the simulator eagerly (default: as the policy trained, compiled unless it recorded otherwise)")
    args = parser.parse_args()
    if args.controllers is not None and "pd" not in args.controllers:
        parser.error(f"--controllers {' '.join(args.controllers)}: pd is required, every result is paired against it")
    torch.set_num_threads(args.threads)
    # once, before any file is written: rewriting a tracked results file would mark the tree
    # dirty for every file after the first
    commit = git_commit()
    if args.verify is not None:
        verify(args)
        return
    if args.resummarize is not None:
        hold_for_command(*args.resummarize, what="ablation results", hint="wait for the run writing it to finish")
        for path in args.resummarize:
            resummarize(path, commit)
        return
    results_dir = args.results or Path("runs/quick/results" if args.quick else "results")
    fig_dir = args.figures or Path("runs/quick/figures" if args.quick else "docs/figures")
    # each sweep's results file stands for its figures too (named after the sweep)
    hold_for_command(*(results_dir / f"ablation_{name}.json" for name in args.sweeps), what="ablation results",
                     hint="wait for it to finish, or choose another --results")

    def checkpoint(kind: str, regime: str, given: list[Path] | None) -> Path:
        if given:
            return given[0 if regime == "horizontal" or len(given) == 1 else 1]
        return CHECKPOINT_DIR / f"{kind}_{regime}.pt"

    for name in args.sweeps:
        sweep, regime = SWEEPS[name], SWEEP_REGIME[name]
        policy_path = checkpoint("policy", regime, args.policy)
        blind_path = checkpoint("policy", regime, args.blind_policy) if args.blind_policy else (
            CHECKPOINT_DIR / f"policy_{regime}_trained_blind.pt")
        oracle_path = checkpoint("policy", regime, args.oracle_policy) if args.oracle_policy else None
        controllers = tuple(args.controllers or RL_CONTROLLERS)
        if args.controllers is None and oracle_path is None:
            controllers = tuple(c for c in controllers if c != "trained_oracle")
        elif "trained_oracle" in controllers and (oracle_path is None or not oracle_path.exists()):
            parser.error("trained_oracle needs --oracle-policy, a policy trained with --wind-input truth"
                         + (f"; none at {oracle_path}" if oracle_path is not None else ""))
        if args.controllers is None and not blind_path.exists():
            controllers = tuple(c for c in controllers if c != "trained_blind")
            print(f"{name}: no trained-blind policy at {repo_relative(blind_path)}; flying {', '.join(controllers)}")
        elif "trained_blind" in controllers and not blind_path.exists():
            parser.error(f"--controllers trained_blind: no trained-blind policy at {blind_path} (--blind-policy)")
        payload = load_policy(policy_path)[1]
        # the policy's own airframe: the network checks its channels, the filter models its drag
        estimator = load_estimator(regime, checkpoint("estimator", regime, args.estimator),
                                   config=policy_env_config(payload))
        monitor = MonitorConfig() if args.monitor else None
        scenarios, override = sweep_setup(sweep, args.quick, monitor)
        compile_step = False if args.eager else policy_compile_step(payload)
        start = time.perf_counter()
        batch = min(args.batch or scenarios.batch_size[0], scenarios.batch_size[0])
        trained = {c: path for c, path in (("trained_blind", blind_path), ("trained_oracle", oracle_path)) if c in controllers}
        results = fly_controllers(regime, scenarios, policy_path, estimator, controllers, batch=batch,
                                  progress=True, config_override=override, compile_step=compile_step,
                                  trained_policies=trained)
        # the flights' own env config (the policy's, shortened under --quick) schedules each pattern
        flown_config = policy_env_config(payload) if override is None else override(policy_env_config(payload))
        table = episode_table(scenarios, results, pattern_starts(scenarios, flown_config))
        summary = summarize_ablation(name, table, controllers)
        summary.update(command=command_line(sys.argv), git_commit=commit, platform=platform_info(), policy=repo_relative(policy_path),
                       **{key: repo_relative(trained[c]) if c in trained else None for c, key in TRAINED_POLICY_KEYS.items()},
                       estimator=repo_relative(checkpoint("estimator", regime, args.estimator)), quick=args.quick, batch=batch,
                       estimator_manifest=getattr(estimator, "manifest", {}).get("metrics"), compile_step=compile_step,
                       monitor=None if monitor is None else config_to_dict(monitor), wall_time_s=time.perf_counter() - start)
        write_json(results_dir / f"ablation_{name}.json", summary)
        if set(figures.FIGURE_CONTROLLERS) <= set(controllers):
            drawn = ", ".join(str(p) for p in figures.ablation_figures(name, scenarios, results, summary, fig_dir))
        else:
            drawn = f"none (they need the controllers {', '.join(figures.FIGURE_CONTROLLERS)})"
        xy = summary["rmse_xy"]
        vs_pd = "; ".join(f"{c} {xy[c]['improvement']:.1f} % (95 % CI {xy[c]['ci_low']:.1f} to {xy[c]['ci_high']:.1f}), "
                          f"wins {xy[c]['wins']}/{xy[c]['n']}" for c in controllers if c != "pd")
        print(f"{name}: {summary['episodes']} episodes, {time.perf_counter() - start:.0f} s; xy RMSE reduction vs PD: {vs_pd}; "
              f"figures: {drawn}")


def resummarize(path: Path, commit: str) -> None:
    recorded = json.loads(path.read_text())
    table = episode_table_from_json(recorded["episodes_table"])
    summary = summarize_ablation(recorded["sweep"], table, recorded["controllers"])
    if summary["episodes_table"] != recorded["episodes_table"]:
        sys.exit(f"{path}: the episode table does not survive the round trip; nothing written")
    added = [key for key in summary if key not in recorded]
    changed = [key for key in summary if key in recorded and summary[key] != recorded[key]]
    write_json(path, recorded | summary | {"summarized_by": {"command": command_line(sys.argv), "git_commit": commit}})
    print(f"{path} (flown at {recorded['git_commit']}): tables added: {', '.join(added) or 'none'}; "
          f"changed: {', '.join(changed) or 'none'}")


def verify(args: argparse.Namespace) -> None:
    """Re-fly a results file's batches and report against the contract (docs/simulator.md, "Exact
    replay"): bitwise on the platform that made it, else the deviation distribution and whether
    the re-flight is equivalent to the record; exits 1 where the contract does not hold."""
    results = json.loads(args.verify.read_text())
    chunks = range(*(int(x) for x in args.chunks.split(":"))) if args.chunks else None
    t0 = time.perf_counter()
    agreement, episodes = verify_ablation(results, chunks)
    batch = results.get("batch", results["episodes"])
    recorded = results.get("platform")
    quick = flown_quick(results)
    print(f"{args.verify} ({results['sweep']}, recorded at {results['git_commit']}), batches of {batch}: "
          f"{'all' if chunks is None else f'{chunks.start}:{chunks.stop}'} ({episodes} episodes), "
          f"{'compiled' if results.get('compile_step') else 'eager'}, {time.perf_counter() - t0:.0f} s")
    print(f"  recorded on: {recorded or 'not recorded'}\n  flown on:    {platform_info()}")
    holds = True
    for name, agreed in agreement.items():
        ok, verdict = replay_verdict(agreed, recorded, CROSS_PLATFORM_RTOL.get((results["sweep"], quick)))
        holds &= ok
        print(f"  {name}: {verdict}")
    if not holds:
        sys.exit(1)

if __name__ == "__main__":
    main()
