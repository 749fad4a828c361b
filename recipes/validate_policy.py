"""Fly a saved policy and PD on its regime's validation sweep and print the trainer's evaluation
metrics, optionally with the runtime monitor on (docs/rl.md, "Runtime monitor").

    python recipes/validate_policy.py --policy quadwind_trl/checkpoints/policy_horizontal.pt
    python recipes/validate_policy.py --policy runs/ppo_horizontal/policy.pt --monitor --out runs/val_monitor.json
    python recipes/validate_policy.py --policy P --monitor --episodes 2 --quick --eager     # seconds

The flights and metrics are the training run's periodic evaluation (the selection of the sweep
in one batch, ``paired_metrics``, ``validation_score``); ``--monitor`` switches the monitor on
with its defaults (``MonitorConfig``) in the policy's own env and adds the share of the scored
steps the monitor held the residual at zero. Report a policy with and without it.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

from quadwind_trl.config import MonitorConfig, config_to_dict
from quadwind_trl.evaluation.policy_validation import validate_policy
from quadwind_trl.manifest import command_line, git_commit, platform_info, repo_relative, write_json
from quadwind_trl.outputs import hold_for_command


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policy", type=Path, required=True, help="a policy.pt (or training checkpoint)")
    parser.add_argument("--estimator", type=Path, default=None, help="default: the estimator the policy trained with")
    parser.add_argument("--monitor", action="store_true", help="fly the policy with the runtime monitor (MonitorConfig defaults)")
    parser.add_argument("--episodes", type=int, default=None, help="an evenly spread subset of the sweep (default: all)")
    parser.add_argument("--quick", action="store_true", help="the PPO recipes' --quick flights (short, from the pattern start)")
    parser.add_argument("--eager", action="store_true", help="fly the simulator eagerly (default: as the policy trained)")
    parser.add_argument("--out", type=Path, default=None, help="write the metrics and the manifest here (JSON)")
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
        m = validate_policy(args.policy, args.estimator, monitor=monitor, episodes=args.episodes, quick=args.quick,
                            compile_step=False if args.eager else None, progress=not args.no_progress)
    except (FileNotFoundError, ValueError) as err:  # a missing checkpoint, --episodes out of range
        raise SystemExit(f"error: {err}") from None
    m["eval_s"] = time.perf_counter() - t0
    authority = (f", monitor active {100 * m['monitor_active_fraction']:.1f} % of scored steps "
                 f"(at most {100 * m['monitor_active_fraction_max']:.1f} % in one episode)" if monitor else "")
    print(f"{m['episodes']} episodes{' with the runtime monitor' if monitor else ''}: rmse {m['rmse']:.3f} m vs PD "
          f"{m['pd_rmse']:.3f} m (RMSE reduction {m['improvement_vs_pd']:+.1f} %; xy {m['improvement_rmse_xy_pct']:+.1f} %, "
          f"z {m['improvement_rmse_z_pct']:+.1f} %; positive = better than PD), win rate {m['win_rate']:.2f}, "
          f"crashed {m['crashed']}, validation score {m['validation_score']:.3f} m{authority}, {m['eval_s']:.0f} s")
    if args.out is not None:
        write_json(args.out, {"metrics": m, "policy": repo_relative(args.policy),
                              "estimator": None if args.estimator is None else repo_relative(args.estimator),
                              "monitor": None if monitor is None else config_to_dict(monitor), "episodes": args.episodes,
                              "quick": args.quick, "eager": args.eager, "command": command_line(sys.argv),
                              "git_commit": commit, "platform": platform_info()})
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
