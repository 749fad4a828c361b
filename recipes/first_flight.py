"""The shipped wind-aware policy against PD on a few paper-scale episodes in the wind: the real
result, in about a minute on one core, before the toy pipeline (``scripts/quickstart.sh`` runs it
first). No training: the shipped policy and estimator fly as the paper's system flies.

    python recipes/first_flight.py                     # 16 episodes, 30 s patterns, U = 10 m/s
    python recipes/first_flight.py --episodes 8 --seconds 60 --wind 12

The episodes (``quadwind_trl.evaluation.first_flight``): the paper's vehicle, sensors and
atmosphere, horizontal patterns in turn at 100 m, flown from their start; mean wind ``--wind``
at the 10 m reference height, turbulence intensity ``--intensity``, the other wind parameters
drawn over the RL training ranges with a fixed seed (``FIRST_FLIGHT_SEED``, used for nothing
else). Prints each episode's xy RMSE for both and the paired improvement; writes
``first_flight.json`` (per-episode table, paired statistics, command, commit, platform) and
``first_flight.png`` (the episode of median improvement: both controllers' error in a frame
that follows the reference, the error over time, the wind) to ``--out``.

Why 16 episodes of 30 s: the two controllers fly one batch each, so the wall time grows with the
pattern's length and hardly with the episode count (on one thread: 16 x 30 s in 51 s, 8 x 60 s in
99 s), and the quickstart has about a minute for this.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

from quadwind_trl.estimator import load_estimator
from quadwind_trl.evaluation.figures import tracking_error_episode
from quadwind_trl.evaluation.first_flight import FirstFlight, fly_first_flight, summarize_first_flight
from quadwind_trl.manifest import CHECKPOINT_DIR, command_line, git_commit, platform_info, repo_relative, write_json
from quadwind_trl.outputs import hold_for_command
from quadwind_trl.regimes import HORIZONTAL_RL

POLICY = CHECKPOINT_DIR / "policy_horizontal.pt"
ESTIMATOR = CHECKPOINT_DIR / "estimator_horizontal.pt"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    default = FirstFlight()
    parser.add_argument("--episodes", type=int, default=default.episodes)
    parser.add_argument("--seconds", type=float, default=default.pattern_s, help="pattern flown per episode, from its start (s)")
    parser.add_argument("--wind", type=float, default=default.wind_m_s, help="mean wind U at the 10 m reference height (m/s)")
    parser.add_argument("--intensity", type=float, default=default.intensity, help="turbulence intensity")
    parser.add_argument("--out", type=Path, default=Path("runs/quick/first_flight"))
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    hold_for_command(args.out, what="first flight folder", hint="wait for it to finish, or choose another --out")
    torch.set_num_threads(args.threads)
    try:
        flight = FirstFlight(episodes=args.episodes, pattern_s=args.seconds, wind_m_s=args.wind, intensity=args.intensity)
    except ValueError as err:
        parser.error(str(err))
    commit = git_commit()
    lo, hi = HORIZONTAL_RL.wind_speed_m_s
    print(f"First flight: the shipped wind-aware policy ({repo_relative(POLICY)}, its estimator in the loop) against PD, "
          f"no training:\n  {flight.episodes} paper-scale episodes, horizontal patterns at {flight.ranges.altitude_m[0]:g} m "
          f"({flight.flights.describe()}); U = {flight.wind_m_s:g} m/s at 10 m (the policy trained on {lo:g}-{hi:g} m/s), "
          f"intensity {flight.intensity:g}, seed {flight.seed}", flush=True)
    start = time.perf_counter()
    scenarios, results = fly_first_flight(flight, POLICY, load_estimator("horizontal", ESTIMATOR))
    seconds = time.perf_counter() - start
    summary = summarize_first_flight(flight, scenarios, results)
    table = summary["episodes_table"]
    print("  episode  pattern          wind from   PD xy RMSE   RL xy RMSE   reduction")
    for i, (traj, pd, rl) in enumerate(zip(table["trajectory"], table["pd_rmse_xy"], table["aware_rmse_xy"])):
        print(f"  {i:7d}  {traj:<16} {summary['wind_dir_deg'][i]:6.0f} deg   {pd:8.2f} m   {rl:8.2f} m   {100 * (1 - rl / pd):+7.1f} %")
    xy, z = summary["rmse_xy"], summary["rmse_z"]
    print(f"  mean                                 {xy['aware']['baseline_mean']:8.2f} m   {xy['aware']['other_mean']:8.2f} m")
    print(f"xy RMSE reduction, wind-aware RL vs PD on the same episodes: {xy['aware']['improvement']:+.1f} % "
          f"(bootstrap 95 % CI {xy['aware']['ci_low']:+.1f} to {xy['aware']['ci_high']:+.1f}), RL better in "
          f"{xy['aware']['wins']}/{xy['aware']['n']} episodes; height RMSE PD {z['aware']['baseline_mean']:.2f} m, "
          f"RL {z['aware']['other_mean']:.2f} m; crashes PD {summary['crashed']['pd']}, RL {summary['crashed']['aware']}; "
          f"flown in {seconds:.0f} s")
    row = summary["shown_episode"]
    title = (f"{table['trajectory'][row]}, U = {flight.wind_m_s:g} m/s at 10 m, intensity "
             f"{flight.intensity:g}\nepisode {row} of {flight.episodes} (the median reduction)")
    figure = tracking_error_episode(results, row, title, args.out / "first_flight.png")
    summary.update(command=command_line(sys.argv), git_commit=commit, platform=platform_info(), policy=repo_relative(POLICY),
                   estimator=repo_relative(ESTIMATOR), compile_step=False, wall_time_s=seconds, figure=repo_relative(figure))
    write_json(args.out / "first_flight.json", summary)
    print("These are the shipped policy's numbers: it trained at paper scale (docs/results.md has its 225-episode "
          "evaluation). The toy pipeline (scripts/quickstart.sh runs it beside this flight) retrains everything at toy scale in minutes; its numbers say nothing "
          "about the method.")
    print(f"Figure: {repo_relative(figure)} (episode {row}, the median reduction); table: {repo_relative(args.out / 'first_flight.json')}")


if __name__ == "__main__":
    main()
