"""Where the shipped policy's worst episodes come from (docs/rl.md, "Where the
tail comes from"): re-fly PD and the wind-aware policy on every episode of the horizontal and OOD
ablation sweeps, in the batch layout their results files record, with a per-step record of the
limits and the policy's inputs; compare the worst episodes with the median ones.

    python recipes/diagnose_tails.py                      # horizontal and OOD, worst 10 each
    python recipes/diagnose_tails.py --sweeps ood --worst 5

The selection rule is the recorded wind-aware xy RMSE, worst first (the worst by wind-aware minus
PD xy RMSE and by z RMSE are listed too); the contrast group is the ``--worst`` episodes around
the median. Flights are kept in ``--flights`` (default ``runs/diagnosis``) and reused when they
were flown with the same policy, estimator and layout (``--refly`` flies again). Writes
``results/diagnosis_tails.json`` and ``docs/figures/diagnosis_*.png``; reports whether the
re-flight reproduced the recorded RMSEs bit for bit.
"""
from __future__ import annotations

import argparse
import filecmp
import json
import sys
import time
from pathlib import Path

import torch

from quadwind_trl.envs.scenarios import STABILITY_NAMES
from quadwind_trl.envs.trajectories import trajectory_name
from quadwind_trl.estimator import load_estimator
from quadwind_trl.evaluation.ablation import episode_table, policy_env_config
from quadwind_trl.manifest import (CHECKPOINT_DIR, command_line, git_commit, platform_info, repo_relative, save_atomic,
                                   write_json)
from quadwind_trl.outputs import hold_for_command
from quadwind_trl.regimes import SWEEPS
from quadwind_trl.rl.policy import load_policy
from quadwind_trl.studies.diagnosis import (OUT_OF_RANGE_Z, SCALAR_INDICATORS, correlations, diagnosis_episode,
                                           diagnosis_groups, episode_indicators, fly_recorded_layout, group_summary,
                                           rank_episodes, reproduction, step_diagnostics)


def flights(sweep: str, recorded: dict, policy: Path, estimator: Path, cache_dir: Path, refly: bool) -> tuple[dict, float]:
    """The re-flown PD and wind-aware flights of ``sweep`` (from the cache when it holds this
    policy, estimator and layout) and the seconds they took to fly."""
    key = {"policy": repo_relative(policy), "estimator": repo_relative(estimator), "batch": recorded["batch"],
           "compile_step": recorded["compile_step"]}
    path = cache_dir / f"{sweep}_flights.pt"
    if path.exists() and not refly:
        cached = torch.load(path, weights_only=False)
        if cached.get("key") == key:
            return cached["results"], cached["wall_s"]
    start = time.perf_counter()
    results = fly_recorded_layout(recorded, policy, load_estimator("horizontal", estimator))
    wall_s = time.perf_counter() - start
    path.parent.mkdir(parents=True, exist_ok=True)
    save_atomic({"key": key, "results": results, "wall_s": wall_s}, path)
    return results, wall_s


def episode_row(scenarios, table, indicators: dict, row: int) -> dict:
    """One episode's world, RMSEs and indicators, JSON-ready."""
    sc = scenarios[row]
    out = {"row": row, "case_id": int(sc["case_id"]), "trajectory": trajectory_name(int(sc["traj_id"])),
           "wind_speed_ref_m_s": float(sc["wind_speed_ref_m_s"]), "turb_intensity": float(sc["turb_intensity"]),
           "shear_alpha": float(sc["shear_alpha"]), "turb_length_scale_m": float(sc["turb_length_scale_m"]),
           "stability": STABILITY_NAMES[int(sc["stability"])]}
    for name in ("pd", "aware"):
        out[name] = {"rmse_xy": float(table[f"{name}_rmse_xy"][row]), "rmse_z": float(table[f"{name}_rmse_z"][row]),
                     "crashed": bool(table[f"{name}_crashed"][row]),
                     **{k: float(indicators[name][k][row]) for k in SCALAR_INDICATORS}}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sweeps", nargs="+", default=["horizontal", "ood"], choices=["horizontal", "ood"])
    parser.add_argument("--worst", type=int, default=10, help="episodes in the worst and in the median group")
    parser.add_argument("--policy", type=Path, default=CHECKPOINT_DIR / "policy_horizontal.pt")
    parser.add_argument("--estimator", type=Path, default=CHECKPOINT_DIR / "estimator_horizontal.pt")
    parser.add_argument("--recorded", type=Path, default=Path("results"), help="folder of the ablation_<sweep>.json to re-fly")
    parser.add_argument("--flights", type=Path, default=Path("runs/diagnosis"), help="flight cache folder")
    parser.add_argument("--refly", action="store_true", help="fly again even where the cache holds the flights")
    parser.add_argument("--out", type=Path, default=Path("results/diagnosis_tails.json"))
    parser.add_argument("--figures", type=Path, default=Path("docs/figures"))
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    hold_for_command(args.out, what="tail diagnosis", hint="wait for it to finish, or choose another --out")
    torch.set_num_threads(args.threads)
    commit = git_commit()
    actor, payload = load_policy(args.policy)
    config = policy_env_config(payload)
    obs_clip = payload["env_spec"].get("obs_clip")
    summary: dict = {"command": command_line(sys.argv), "git_commit": commit, "platform": platform_info(),
                     "policy": repo_relative(args.policy), "estimator": repo_relative(args.estimator),
                     "out_of_range_z": OUT_OF_RANGE_Z, "obs_clip": obs_clip, "sweeps": {}}
    groups_fig = {}
    for sweep in args.sweeps:
        recorded = json.loads((args.recorded / f"ablation_{sweep}.json").read_text())
        scenarios = SWEEPS[sweep].scenarios()
        results, wall_s = flights(sweep, recorded, args.policy, args.estimator, args.flights, args.refly)
        diag = {"pd": step_diagnostics(results["pd"], scenarios, payload, config),
                "aware": step_diagnostics(results["aware"], scenarios, payload, config, actor)}
        indicators = {name: episode_indicators(d, obs_clip) for name, d in diag.items()}
        table = episode_table(scenarios, results)
        ranks = rank_episodes(table, args.worst)
        worst, median = ranks["worst_xy"], ranks["median_xy"]
        recorded_policy = Path(recorded["policy"])
        summary["sweeps"][sweep] = {
            "recorded": {"file": repo_relative(args.recorded / f"ablation_{sweep}.json"), "git_commit": recorded["git_commit"],
                         "policy": recorded["policy"], "platform": recorded.get("platform"),
                         "policy_same_file": recorded_policy.exists() and filecmp.cmp(recorded_policy, args.policy, shallow=False)},
            "batch": recorded["batch"], "compile_step": recorded["compile_step"], "flight_wall_s": wall_s,
            "reproduction": {"all": reproduction(recorded, results),
                             "selected": reproduction(recorded, results, sorted(set().union(*ranks.values())))},
            "rules": {"worst_xy": "largest wind-aware xy RMSE", "worst_excess_xy": "largest wind-aware minus PD xy RMSE",
                      "worst_z": "largest wind-aware z RMSE", "median_xy": "around the median wind-aware xy RMSE"},
            "selection": ranks,
            "groups": {rule: group_summary(indicators, rows, config.residual.acts_on)
                       for rule, rows in (("worst_xy", worst), ("median_xy", median), ("all", range(table.batch_size[0])))},
            "episodes": {"worst_xy": [episode_row(scenarios, table, indicators, r) for r in worst],
                         "worst_excess_xy": [episode_row(scenarios, table, indicators, r) for r in ranks["worst_excess_xy"]],
                         "worst_z": [episode_row(scenarios, table, indicators, r) for r in ranks["worst_z"]]},
            "correlations": correlations(table, indicators),
        }
        row = worst[0]
        diagnosis_episode(
            diag, row, f"{sweep}: worst episode (row {row}, {trajectory_name(int(scenarios['traj_id'][row]))}, "
            f"U = {float(scenarios['wind_speed_ref_m_s'][row]):g} m/s, intensity {float(scenarios['turb_intensity'][row]):g})",
            args.figures / f"diagnosis_{sweep}_worst.png", OUT_OF_RANGE_Z, obs_clip)
        labels = [f"{r}: {trajectory_name(int(scenarios['traj_id'][r]))[:10]} U{float(scenarios['wind_speed_ref_m_s'][r]):g}"
                  for r in worst] + ["median group"]
        groups_fig[sweep] = {"labels": labels, **{
            key: {name: [float(table[f"{name}_{key}"][r]) if key == "rmse_xy" else float(indicators[name][key][r])
                         for r in worst] + [float(table[f"{name}_{key}"][median].mean()) if key == "rmse_xy"
                                             else float(indicators[name][key][median].mean())]
                  for name in ("pd", "aware")}
            for key in ("rmse_xy", "tilt_cmd_saturated", "tilt_beyond_limit", "thrust_saturated", "obs_out_of_range",
                        "wind_estimate_error")}}
        rep = summary["sweeps"][sweep]["reproduction"]["all"]
        print(f"{sweep}: flights {wall_s:.0f} s; reproduction " + ", ".join(
            f"{n} {r['identical']}/{r['values']} identical (max rel {r['max_relative']:.2g})" for n, r in rep.items()))
    diagnosis_groups(groups_fig, args.figures / "diagnosis_tails_summary.png")
    write_json(args.out, summary)
    print(f"wrote {args.out} and figures in {args.figures}")


if __name__ == "__main__":
    main()
