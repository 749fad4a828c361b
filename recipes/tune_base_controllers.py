"""The validation search for the classical base controllers: each family's gain or filter constant
on a grid, flown on the regime's validation sweep (the trainer's 45 horizontal, 48 vertical
episodes; never a test sweep) and scored as the trainer scores a policy (mean RMSE plus the mean
of the worst tenth; lower is better); a family keeps its lowest score among the candidates that
crash no more often than PD (``studies.base_search.select_candidate``).

    python recipes/tune_base_controllers.py                      # both regimes, every family
    python recipes/tune_base_controllers.py --regimes horizontal --families pid
    python recipes/tune_base_controllers.py --quick              # three episodes, short flights, small grids
    python recipes/tune_base_controllers.py --families l1         # one family more, beside those already flown

Families (``ControllerConfig``): ``pid`` the integral gain ``Ki`` (all three axes; the integral
clamped at 3 m s), ``dob`` the disturbance observer's filter time constant, ``l1`` the filter time
constant of L1 adaptive control's force (its predictor pole at the config's default), ``pid_ff``
the integral gain on top of wind feed-forward from the shipped estimator (``Ki = 0`` is PD with
feed-forward alone), ``dob_inner`` the inner loop's stiffness under the chosen observer (``K_R x s``,
``K_omega x sqrt(s)``: the attitude loop's damping kept, its speed times ``sqrt(s)``; the classical
answer to a still-air tracking lag, so that it is not credited to learning), ``dob_inner_tilt`` the
commanded-tilt limit under the chosen ``dob_inner`` (the episodes where the wind costs the
observer most are where that limit binds: ``recipes/observer_bound.py``). The candidates of a
family fly in one batch, the tilt limit's one batch each (``studies.base_search``). Every family
flies in the env the shipped policy of the regime trained in (its config, its estimate's EMA and
query interval), so the chosen controllers see the worlds the RL sees. Writes
``results/base_search_<regime>.json`` (``--quick``: under ``runs/quick/results``): every
candidate's score, means, gains over PD and crashes, the chosen value per family, the command,
commit and platform. A run of some families keeps the others of an existing file, provided that
file was flown in the same env on the same episodes (each family records the commit and command
that flew it). The chosen values are copied into ``regimes.CLASSICAL_CHOICES`` by hand,
and docs/simulator.md ("Classical base controllers") shows the tables.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import torch

from quadwind_trl.config import ControllerConfig, config_to_dict, stiffer_inner_loop
from quadwind_trl.estimator import load_estimator
from quadwind_trl.manifest import command_line, git_commit, platform_info, write_json
from quadwind_trl.outputs import hold_for_command
from quadwind_trl.regimes import CLASSICAL_CHOICES
from quadwind_trl.rl.envs import policy_env_settings
from quadwind_trl.studies.base_search import fly_candidates, select_candidate, validation_setup

KI_GRID = (0.0, 0.5, 1.0, 2.0, 3.0, 4.0, 6.0)  # 1/s^3, every axis
# s; down to two control steps: the horizontal search's best was its smallest value at 0.05 s
TAU_GRID = (0.02, 0.03, 0.05, 0.1, 0.2, 0.4, 0.8, 1.6)
# the inner loop's stiffness: K_R x s and K_omega x sqrt(s) keep the attitude loop's damping ratio
# (about 2 at the paper's gains: overdamped, its slow pole near 3 rad/s) and raise its speed by
# sqrt(s); s = 8 puts the slow pole near 9 rad/s, half the motors' 20 rad/s (one motor time constant)
INNER_SCALE_GRID = (1.0, 2.0, 3.0, 4.0, 6.0, 8.0)
# deg: the cascade's commanded-tilt limit under the chosen stiffer-inner-loop observer, from the
# paper's 35 deg; the vehicle holds its height up to acos(1 / 2.5) = 66 deg at its maximum thrust
# (2.5 x hover), and attitude-hold autopilots default to 35-45 deg (PX4's MPC_TILTMAX_AIR: 45 deg)
TILT_GRID = (35.0, 40.0, 45.0, 50.0, 55.0)
QUICK_KI, QUICK_TAU, QUICK_INNER, QUICK_TILT = (0.0, 2.0), (0.2, 0.8), (1.0, 3.0), (35.0, 45.0)


def families(quick: bool, regime: str = "horizontal") -> dict[str, tuple[str, str, list[ControllerConfig]]]:
    """``{family: (searched field, base wind input, candidates)}``; ``dob_inner`` searches the inner
    loop under the regime's chosen observer (``regimes.CLASSICAL_CHOICES``), ``dob_inner_tilt`` the
    commanded-tilt limit under the chosen ``dob_inner``."""
    ki, tau, inner, tilt = (QUICK_KI, QUICK_TAU, QUICK_INNER, QUICK_TILT) if quick else (KI_GRID, TAU_GRID, INNER_SCALE_GRID, TILT_GRID)
    dob = ControllerConfig(disturbance="observer", observer_tau_s=CLASSICAL_CHOICES[regime]["dob_tau_s"])
    dob_inner = stiffer_inner_loop(dob, CLASSICAL_CHOICES[regime]["dob_inner_scale"])
    axes = lambda k: (k, k, k)  # noqa: E731
    return {
        "pid": ("ki_pos", "zero", [ControllerConfig(ki_pos=axes(k)) for k in ki]),
        "dob": ("observer_tau_s", "zero", [ControllerConfig(disturbance="observer", observer_tau_s=t) for t in tau]),
        "l1": ("observer_tau_s", "zero", [ControllerConfig(disturbance="l1", observer_tau_s=t) for t in tau]),
        "pid_ff": ("ki_pos", "estimate", [ControllerConfig(ki_pos=axes(k), disturbance="wind_model") for k in ki]),
        "dob_inner": ("k_att", "zero", [stiffer_inner_loop(dob, s) for s in inner]),
        "dob_inner_tilt": ("max_tilt_deg", "zero", [replace(dob_inner, max_tilt_deg=t) for t in tilt]),
    }


def kept_families(out: Path, flown: list[str]) -> dict:
    """The families of an existing search file that this run does not fly, kept as they are, each
    with the commit and command that flew it."""
    if not out.exists():
        return {}
    earlier = json.loads(out.read_text())
    provenance = {"git_commit": earlier.get("git_commit"), "command": earlier.get("command")}
    return {name: provenance | entry for name, entry in earlier["families"].items() if name not in flown}


def _known(now, earlier):
    """``now`` without the dict keys ``earlier`` lacks, at any depth: settings added to the config
    since the earlier file was written (at their defaults, which leave every earlier law as it was)."""
    if isinstance(now, dict) and isinstance(earlier, dict):
        return {k: _known(v, earlier[k]) for k, v in now.items() if k in earlier}
    return now


def check_same_flights(out: Path, report: dict) -> None:
    """A file that keeps families flown earlier must describe one search: the same env, estimate,
    episodes and simulator step, and the same PD on them."""
    earlier = json.loads(out.read_text())
    for key in ("config", "estimate", "episodes", "compile_step", "pd"):
        now = json.loads(json.dumps(report[key], default=str))  # as the file holds it
        if earlier.get(key) != _known(now, earlier.get(key)):
            raise SystemExit(f"{out}: its {key!r} differs from this run's, so its other families were flown in other "
                             f"conditions; fly every family (--families {' '.join(families(False))})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--regimes", nargs="+", default=["horizontal", "vertical"], choices=["horizontal", "vertical"])
    parser.add_argument("--families", nargs="+", default=list(families(False)), choices=list(families(False)))
    parser.add_argument("--quick", action="store_true", help="three validation episodes, 10 s patterns, two candidates a family")
    parser.add_argument("--results", type=Path, default=None, help="results directory (default results/, --quick runs/quick/results)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--compile", action=argparse.BooleanOptionalAction, default=None,
                        help="the compiled simulator step (default: as the regime's shipped policy trained; --quick: eager)")
    args = parser.parse_args()
    results = args.results or Path("runs/quick/results" if args.quick else "results")
    outputs = [results / f"base_search_{regime}.json" for regime in args.regimes]
    hold_for_command(*outputs, what="base-controller search results", hint="wait for it to finish, or choose another --results")
    torch.set_num_threads(args.threads)
    commit = git_commit()  # before this run writes its (tracked) outputs: a second regime's file is not "dirty"

    for regime, out in zip(args.regimes, outputs):
        config, scenarios, compile_step, payload = validation_setup(regime, args.quick, args.compile)
        estimator = load_estimator(regime, config=config)
        # the estimate the policy sees (its EMA and query interval); the rest is each family's own
        settings = {key: value for key, value in policy_env_settings(payload["env_spec"], estimator).items()
                    if key in ("ema_tau_s", "estimate_every_s")}
        report = {"command": command_line(sys.argv), "git_commit": commit, "platform": platform_info(),
                  "regime": regime, "episodes": scenarios.batch_size[0], "compile_step": compile_step,
                  "estimate": settings, "config": config_to_dict(config), "families": kept_families(out, args.families)}
        pd = None
        for name in args.families:
            field, wind, candidates = families(args.quick, regime)[name]
            candidates = [replace(c, feedback=config.controller.feedback) for c in candidates]
            start = time.perf_counter()
            flown = fly_candidates(regime, candidates, scenarios, estimator, base_wind_input=wind, config=config,
                                   spec_settings=settings, compile_step=compile_step, progress=True)
            wall = time.perf_counter() - start
            if pd is None:  # the integral family's Ki = 0 row is the paper's PD (the search's reference)
                pd = fly_candidates(regime, [config.controller], scenarios, estimator, base_wind_input="zero", config=config,
                                    spec_settings=settings, compile_step=compile_step)[0]
            rows = [dict(value=getattr(c.controller, field), **c.row(pd)) for c in flown]
            best = select_candidate(rows, int(pd.crashed.sum()))
            report["families"][name] = {"field": field, "base_wind_input": wind, "wall_time_s": wall, "candidates": rows,
                                        "chosen": best["value"], "git_commit": report["git_commit"],
                                        "command": report["command"]}
            print(f"{regime} {name} ({field}, {len(candidates)} candidates x {scenarios.batch_size[0]} episodes, {wall:.0f} s):")
            for r in rows:
                mark = " <- chosen" if r is best else ""
                print(f"  {r['value']}: score {r['validation_score']:.3f} m, xy {r['rmse_xy']:.3f} m "
                      f"({r['improvement_xy_pct']:+.1f} %), z {r['rmse_z']:.3f} m ({r['improvement_z_pct']:+.1f} %), "
                      f"wins {r['wins']}/{r['episodes']}, crashed {r['crashed']}{mark}")
        report["pd"] = pd.row(pd)
        if report["families"].keys() - set(args.families):
            check_same_flights(out, report)
        write_json(out, report)
        print(f"wrote {out}")


if __name__ == "__main__":
    main()
