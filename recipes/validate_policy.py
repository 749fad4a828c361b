"""Fly saved policies and PD on their regime's validation sweep and print the trainer's evaluation
metrics, optionally with the runtime monitor on (docs/rl.md, "Runtime monitor"), and each policy
against PD within and beyond the flight envelope.

    python recipes/validate_policy.py --policy quadwind_trl/checkpoints/policy_horizontal.pt
    python recipes/validate_policy.py --policy runs/ppo_horizontal/policy.pt --monitor --out runs/val_monitor.json
    python recipes/validate_policy.py --policy P1 P2 P3 --out runs/val.json   # one regime, PD flown once
    python recipes/validate_policy.py --policy P --monitor --episodes 2 --quick --eager     # seconds

The flights and metrics are the training run's periodic evaluation (the selection of the sweep
in one batch, ``paired_metrics``, ``validation_score``); ``--monitor`` switches the monitor on
with its defaults (``MonitorConfig``) in the policy's own env and adds the share of the scored
steps the monitor held the residual at zero. Report a policy with and without it. Several
policies (one regime, one env config) fly the same episodes as PD, flown once; each gets the
metrics it gets alone. ``--out`` also holds one row per episode (its wind case, airspeed demand
and margin to the envelope, PD's and each policy's RMSEs and crash flag) and the split of the
episodes within (gust margin >= 0) and beyond the envelope, which is printed as a table.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

from quadwind_trl.config import MonitorConfig, config_to_dict
from quadwind_trl.evaluation.envelope import GUST_SIGMAS
from quadwind_trl.evaluation.policy_validation import PolicyValidation, envelope_split, episode_rows, validate_policies
from quadwind_trl.manifest import command_line, git_commit, platform_info, repo_relative, write_json
from quadwind_trl.outputs import hold_for_command


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policy", type=Path, nargs="+", required=True,
                        help="one or more policy.pt (or training checkpoints) of one regime")
    parser.add_argument("--estimator", type=Path, default=None, help="default: the estimator each policy trained with")
    parser.add_argument("--monitor", action="store_true", help="fly the policies with the runtime monitor (MonitorConfig defaults)")
    parser.add_argument("--episodes", type=int, default=None, help="an evenly spread subset of the sweep (default: all)")
    parser.add_argument("--quick", action="store_true", help="the PPO recipes' --quick flights (short, from the pattern start)")
    parser.add_argument("--eager", action="store_true", help="fly the simulator eagerly (default: as the policies trained)")
    parser.add_argument("--out", type=Path, default=None,
                        help="write the metrics, the per-episode rows, the envelope split and the manifest here (JSON)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args()
    if args.out is not None:
        hold_for_command(args.out, what="validation results", hint="wait for it to finish, or choose another --out")
    torch.set_num_threads(args.threads)
    commit = git_commit()
    monitor = MonitorConfig() if args.monitor else None
    t0 = time.perf_counter()
    try:
        result = validate_policies(args.policy, args.estimator, monitor=monitor, episodes=args.episodes, quick=args.quick,
                                   compile_step=False if args.eager else None, progress=not args.no_progress)
    except (FileNotFoundError, ValueError) as err:  # a missing checkpoint, --episodes out of range, mixed policies
        raise SystemExit(f"error: {err}") from None
    eval_s = time.perf_counter() - t0
    for label, m in result.metrics.items():
        m["eval_s"] = eval_s  # all the flights, PD's included
        print(metrics_line(label if len(result.metrics) > 1 else None, m, monitor is not None))
    split = envelope_split(result.episodes)
    print(envelope_table(result, split))
    if args.out is not None:
        policies = {label: {"path": repo_relative(path), "metrics": m}
                    for (label, m), path in zip(result.metrics.items(), args.policy)}
        # one policy: also the layout its files had before several could fly
        first = next(iter(policies.values()))
        single = {"policy": first["path"], "metrics": first["metrics"]} if len(policies) == 1 else {}
        write_json(args.out, {**single, "policies": policies, "by_envelope": split,
                              "episode_rows": episode_rows(result.episodes),
                              "envelope": {"airspeed_m_s": result.envelope.airspeed_m_s, "binding": result.envelope.binding,
                                           "gust_sigmas": GUST_SIGMAS, "pattern_speed_m_s": result.pattern_speed_m_s},
                              "estimator": None if args.estimator is None else repo_relative(args.estimator),
                              "monitor": None if monitor is None else config_to_dict(monitor), "episodes": args.episodes,
                              "quick": args.quick, "eager": args.eager, "command": command_line(sys.argv),
                              "git_commit": commit, "platform": platform_info()})
        print(f"wrote {args.out}")


def metrics_line(label: str | None, m: dict, monitor: bool) -> str:
    """One policy's trainer metrics in a line (``label`` None: the only policy)."""
    authority = (f", monitor active {100 * m['monitor_active_fraction']:.1f} % of scored steps "
                 f"(at most {100 * m['monitor_active_fraction_max']:.1f} % in one episode)" if monitor else "")
    return (f"{f'{label}: ' if label else ''}{m['episodes']} episodes{' with the runtime monitor' if monitor else ''}: "
            f"rmse {m['rmse']:.3f} m vs PD {m['pd_rmse']:.3f} m (RMSE reduction {m['improvement_vs_pd']:+.1f} %; "
            f"xy {m['improvement_rmse_xy_pct']:+.1f} %, z {m['improvement_rmse_z_pct']:+.1f} %; positive = better than PD), "
            f"win rate {m['win_rate']:.2f}, crashed {m['crashed']}, validation score {m['validation_score']:.3f} m"
            f"{authority}, {m['eval_s']:.0f} s")


def envelope_table(result: PolicyValidation, split: dict) -> str:
    """The envelope split as a fixed-width table: one line per group and policy."""
    pct = lambda v: "    -" if v is None else f"{v:+5.1f}"  # noqa: E731  (an empty group has no mean)
    width = max(len(label) for label in result.metrics)
    lines = [f"against the envelope ({result.envelope.airspeed_m_s:.2f} m/s, {result.envelope.binding}-limited; "
             f"gust demand = pattern speed + mean wind + {GUST_SIGMAS:g} sigma_u at the flight altitude):",
             f"{'group':<8}{'episodes':>9}{'PD crashed':>11}  {'policy':<{width}}  {'xy %':>6}{'z %':>6}{'total %':>8}"
             f"{'wins':>8}{'crashed':>8}"]
    for group, block in split.items():
        for label, g in block["policies"].items():
            lines.append(f"{group:<8}{block['episodes']:>9}{block['pd_crashed']:>11}  {label:<{width}}  "
                         f"{pct(g['improvement_rmse_xy_pct']):>6}{pct(g['improvement_rmse_z_pct']):>6}"
                         f"{pct(g['improvement_rmse_pct']):>8}{g['wins']:>5}/{g['episodes']:<2}{g['crashed']:>8}")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
