"""The flight envelope, stated: the airspeed the vehicle can hold in level flight
(tilt limit, rotor thrust, drag) against what every evaluation-sweep cell and training design
demands (pattern speed + mean wind at the flight altitude + gusts), and a simulator check that the
PD stops holding position where the envelope says.

    python recipes/flight_envelope.py                  # ~1 min on one thread

Prints the envelope, the simulator check and two markdown tables; writes
``results/flight_envelope.json`` and ``docs/figures/flight_envelope.png``. Changes nothing it
measures: docs/simulator.md, "Flight envelope", reads the numbers.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import torch

from quadwind_trl.config import EnvConfig, config_to_dict
from quadwind_trl.envs.envelope import flight_envelope
from quadwind_trl.envs import make_scenarios
from quadwind_trl.evaluation.envelope import GUST_SIGMAS, airspeed_demand, pattern_speed
from quadwind_trl.studies.envelope import (
    design_row, design_table, edge_table, edge_wind_speed, envelope_figure, first_not_held, hold_check, sweep_cells,
    sweep_table,
)
from quadwind_trl.manifest import command_line, git_commit, platform_info, write_json
from quadwind_trl.outputs import hold_for_command
from quadwind_trl.regimes import (
    HORIZONTAL_DATASET, HORIZONTAL_RL, SWEEP_REGIME, SWEEPS, VERTICAL_DATASET, VERTICAL_RL,
)

EDGE_INTENSITIES = (0.05, 0.1, 0.15, 0.2, 0.25)
# measured: PD on a held-out design at U = 11 m/s, shear 0.23, 100 m: mean xy RMSE 17.8 m at
# intensity 0.20, 1.00 m at 0.10
OBSERVED = ((11.0, 0.23, 0.20, "PD 17.8 m"), (11.0, 0.23, 0.10, "PD 1.00 m"))
DESIGNS = {"horizontal RL": (HORIZONTAL_RL, "horizontal"), "vertical RL": (VERTICAL_RL, "vertical"),
           "horizontal dataset": (HORIZONTAL_DATASET, "horizontal"), "vertical dataset": (VERTICAL_DATASET, "vertical")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--results", type=Path, default=Path("results/flight_envelope.json"))
    parser.add_argument("--figure", type=Path, default=Path("docs/figures/flight_envelope.png"))
    parser.add_argument("--seconds", type=float, default=25.0, help="length of each steady-wind hover (s)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    hold_for_command(args.results, args.figure, what="flight envelope output",
                     hint="wait for it to finish, or choose another --results / --figure")
    torch.set_num_threads(args.threads)
    start = time.perf_counter()
    commit = git_commit()  # before this run writes its (tracked) outputs
    cfg = EnvConfig()

    validation = {}
    for aero in ("momentum", "static"):  # the default rotor model, and the paper's static law
        vehicle = replace(cfg.vehicle, rotor_aero=aero)
        env = flight_envelope(vehicle, cfg.controller)
        edge = env.airspeed_m_s
        # 0.5 m/s steps from 2 below the edge to 3 above it
        winds = torch.arange(round(2 * edge) / 2 - 2.0, edge + 3.0, 0.5)
        check = hold_check(replace(cfg, vehicle=vehicle), winds, seconds=args.seconds)
        beyond = [a for a, d in zip(check["airspeed_held_m_s"], check["drift_m_s"]) if d > 0.5]  # drifting steadily
        validation[aero] = {"envelope": {**asdict(env), "airspeed_m_s": edge, "binding": env.binding}, **check,
                            "first_wind_not_held_m_s": first_not_held(check),
                            "airspeed_held_beyond_m_s": [min(beyond), max(beyond)]}
        print(f"{aero:8s} envelope {edge:.2f} m/s ({env.binding}-limited; tilt {env.tilt_limited_m_s:.2f}, "
              f"thrust {env.thrust_limited_m_s:.2f}); PD first drifts at {validation[aero]['first_wind_not_held_m_s']:.1f} m/s "
              f"wind, holds {min(beyond):.2f}-{max(beyond):.2f} m/s airspeed beyond it")

    env = flight_envelope(cfg.vehicle, cfg.controller)
    rows = [r for name, sweep in SWEEPS.items() for r in sweep_cells(sweep, SWEEP_REGIME[name], cfg, env)]
    designs = [design_row(name, ranges, regime, cfg, env) for name, (ranges, regime) in DESIGNS.items()]
    print(f"\nEvaluation sweeps: demand = pattern speed + mean wind + {GUST_SIGMAS:g} sigma_u; margin = "
          f"{env.airspeed_m_s:.2f} m/s - demand (positive inside); median / worst shear\n")
    print(sweep_table(rows))
    edges = {regime: edge_wind_speed(ranges, regime, cfg, env, EDGE_INTENSITIES)
             for regime, ranges in (("horizontal", HORIZONTAL_RL), ("vertical", VERTICAL_RL))}
    for regime, edge_rows in edges.items():
        print(f"\nWhere the edge runs, {regime} (lowest 10 m wind speed whose demand exceeds the envelope)\n")
        print(edge_table(edge_rows))
    observed = []
    for u, alpha, intensity, label in OBSERVED:
        sc = make_scenarios(1, wind_speed_ref_m_s=u, shear_alpha=alpha, turb_intensity=intensity, altitude_m=100.0)
        d = {k: v.item() for k, v in airspeed_demand(sc, cfg, pattern_speed(cfg, "horizontal")).items()}
        observed.append({"wind_speed_m_s": u, "shear_alpha": alpha, "intensity": intensity, "label": label, **d,
                         "margin": env.airspeed_m_s - d["demand"], "sustained_margin": env.airspeed_m_s - d["sustained"]})
        print(f"observed {label} (U {u:g}, shear {alpha:g}, I {intensity:g}): mean wind {d['mean_wind']:.1f}, demand "
              f"{d['demand']:.1f} (margin {observed[-1]['margin']:+.1f}), sustained margin {observed[-1]['sustained_margin']:+.1f} m/s")
    print("\nTraining designs (corner: top wind speed the design allows at the altitude, top intensity)\n")
    print(design_table(designs))
    envelope_figure(rows, env, env.tilt_limited_m_s, args.figure,
                    marks=tuple((o["wind_speed_m_s"], o["demand"], f"{o['label']}, I = {o['intensity']:g}, shear {o['shear_alpha']:g}")
                                 for o in observed))
    payload = {"command": command_line(sys.argv), "git_commit": commit, "platform": platform_info(),
               "config": config_to_dict(cfg), "gust_sigmas": GUST_SIGMAS, "envelope": validation["momentum"]["envelope"],
               "validation": validation, "sweep_cells": rows, "designs": designs, "edge_wind_speed": edges,
               "observed": observed,
               "wall_time_s": time.perf_counter() - start}
    write_json(args.results, payload)
    print(f"\nwrote {args.results} and {args.figure} ({payload['wall_time_s']:.0f} s)")


if __name__ == "__main__":
    main()
