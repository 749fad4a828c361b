"""Fly the paper's evaluation sweeps with the PD baseline alone and write the calibration tables.

    python recipes/pd_baseline.py                          # horizontal 225, vertical 144, OOD 90
    python recipes/pd_baseline.py --quick                  # a small smoke subset, short flights
    python recipes/pd_baseline.py --compile                # the same, compiled: ~7 min instead of ~45
    python recipes/pd_baseline.py --sensors sbas --out results/pd_baseline_sbas.json

``--sensors`` changes only the sensing. The first calibration's tables (static rotor thrust,
locally scaled turbulence, walking biases; docs/simulator.md) are in git history only
(``git show cdd87a3:results/legacy/pd_baseline.json``): made from an uncommitted tree, they cannot be
re-flown bit for bit.

Writes ``results/pd_baseline.json`` (per-group statistics of the tracking RMSE and of the
navigation error, with the command and config); the report (``recipes/report.py``) puts them
beside the paper's PD columns in docs/results.md, with the headroom 1 - nav error / RMSE.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

from quadwind_trl.config import SENSOR_PRESETS, EnvConfig, config_to_dict, with_sensor_preset
from quadwind_trl.envs import QuadWindEnv
from quadwind_trl.evaluation.tracking import fly_sweep, sweep_setup, tracking_tables
from quadwind_trl.manifest import command_line, git_commit, platform_info, write_json
from quadwind_trl.outputs import hold_for_command
from quadwind_trl.quick import SWEEP_QUICK
from quadwind_trl.regimes import SWEEPS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sweeps", nargs="+", default=list(SWEEPS), choices=list(SWEEPS))
    parser.add_argument("--sensors", default="rtk", choices=list(SENSOR_PRESETS), help="sensing preset")
    parser.add_argument("--quick", action="store_true", help="one seed, one intensity, 10 s patterns flown from their start")
    parser.add_argument("--out", type=Path, default=Path("results/pd_baseline.json"))
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--compile", action="store_true", help="torch.compile the simulator step")
    args = parser.parse_args()
    hold_for_command(args.out, what="PD baseline results", hint="wait for it to finish, or choose another --out")
    torch.set_num_threads(args.threads)

    cfg = with_sensor_preset(EnvConfig(), args.sensors)
    if args.quick:
        cfg = SWEEP_QUICK.config(cfg)
        print(f"--quick: {SWEEP_QUICK.describe()}; one seed and intensity per sweep")
    report = {"command": command_line(sys.argv), "git_commit": git_commit(), "platform": platform_info(), "sensors": args.sensors,
              "config": config_to_dict(cfg), "sweeps": {}}
    for name in args.sweeps:
        scenarios, _ = sweep_setup(SWEEPS[name], args.quick)  # the flights' change is in cfg already
        env = QuadWindEnv(cfg, batch_size=[scenarios.batch_size[0]], compile_step=args.compile)
        start = time.perf_counter()
        episodes = fly_sweep(env, scenarios, progress=True)
        wall = time.perf_counter() - start
        tables = {m: tracking_tables(episodes, m) for m in ("rmse_xy", "rmse_z", "rmse", "nav_rmse_xy", "nav_rmse_z")}
        report["sweeps"][name] = {"episodes": scenarios.batch_size[0], "wall_time_s": wall, "tables": tables}
        by_wind = tables["rmse_xy"]["by_wind"]
        nav = tables["nav_rmse_xy"]["by_wind"]
        print(f"{name}: {scenarios.batch_size[0]} episodes in {wall:.0f} s; PD xy RMSE (nav error) by wind: "
              + ", ".join(f"U={k}: {v['mean']:.3f} ({nav[k]['mean']:.3f})" for k, v in by_wind.items()))
    write_json(args.out, report)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
