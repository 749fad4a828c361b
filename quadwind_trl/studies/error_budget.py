"""Where the PD baseline's tracking error comes from, and how much of it a controller can remove.

The tracking error is scored on the true position, but the autopilot flies its navigation
estimate. A GPS or barometer bias (``SensorConfig``: bounded Gauss-Markov, or the legacy walks)
shifts that estimate, and with this sensor suite nothing observes the shift: no controller, PD or
learned, can take it out. The
budget separates it from the part a controller can act on by flying the same episodes again with
the sensing idealised and the wind removed:

* sensing ``"navigation"``: the vehicle as shipped (nav filter over biased, noisy sensors);
* ``"no_bias"``: every bias switched off, white noise kept;
* ``"true_state"``: the PD reads the simulator state (the policy and estimator still read sensors);

crossed with wind ``"full"`` (the sweep's), ``"mean_only"`` (intensity 0) and ``"still"`` (no
wind). The wind-aware policy, if asked for, flies the full wind under each sensing, paired with PD
there. The vehicle is the policy's own (its checkpoint's config) unless ``vehicle`` is given
(:func:`on_vehicle`): then the budget is that vehicle's, with the policy's decision interval.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Callable, Literal

from tensordict import TensorDictBase

from ..config import SENSING, EnvConfig, Sensing, with_sensing
from ..envs.runner import FlightResults
from ..estimator import EstimatorBundle
from ..evaluation.ablation import fly_controllers
from ..evaluation.statistics import paired_summary
from .section import Section
from .tables import ci, headroom_pct

Wind = Literal["full", "mean_only", "still"]
WINDS: tuple[Wind, ...] = ("full", "mean_only", "still")


def with_wind(scenarios: TensorDictBase, wind: Wind) -> TensorDictBase:
    """A copy of ``scenarios`` with the turbulence (``"mean_only"``) or all wind (``"still"``) off;
    every other field, seeds included, is kept, so the episodes stay paired."""
    if wind not in WINDS:
        raise ValueError(f"wind={wind!r}; allowed: {WINDS}")
    out = scenarios.clone()
    if wind in ("mean_only", "still"):
        out["turb_intensity"].zero_()
    if wind == "still":
        out["wind_speed_ref_m_s"].zero_()
    return out


def on_vehicle(vehicle: EnvConfig) -> Callable[[EnvConfig], EnvConfig]:
    """A config override that flies ``vehicle``'s physics, sensors and trajectories while keeping
    the policy's residual (decision interval, scales) and reward from its own config."""
    return lambda policy_cfg: replace(vehicle, residual=policy_cfg.residual, reward=policy_cfg.reward)


def _means(res: FlightResults) -> dict[str, float]:
    fields_ = ("rmse_xy", "rmse_z", "nav_rmse_xy", "nav_rmse_z")
    return {k: getattr(res, k).double().mean().item() for k in fields_} | {"crashed": int(res.crashed.sum())}


def error_budget(
    regime: str,
    scenarios: TensorDictBase,
    policy_path: str | Path,
    estimator: EstimatorBundle,
    sensing: tuple[Sensing, ...] = SENSING,
    config_override: Callable[[EnvConfig], EnvConfig] | None = None,
    progress: bool = False,
    winds: tuple[Wind, ...] = WINDS,
    with_policy: bool = True,
) -> dict:
    """PD mean RMSE and navigation error for every (sensing, wind) cell, and (``with_policy``)
    the wind-aware policy against PD in full wind under each sensing (paired: improvement with
    its bootstrap interval, wins)."""
    base = config_override or (lambda cfg: cfg)
    out: dict = {"episodes": scenarios.batch_size[0], "pd": {}, "aware_vs_pd": {}}
    for mode in sensing:
        override = lambda cfg, mode=mode: with_sensing(base(cfg), mode)  # noqa: E731
        out["pd"][mode] = {}
        for wind in winds:
            controllers = ("pd", "aware") if wind == "full" and with_policy else ("pd",)
            res = fly_controllers(regime, with_wind(scenarios, wind), policy_path, estimator, controllers,
                                  progress=progress, config_override=override)
            out["pd"][mode][wind] = _means(res["pd"])
            if "aware" in controllers:
                out["aware_vs_pd"][mode] = {
                    metric: paired_summary(getattr(res["pd"], metric), getattr(res["aware"], metric))
                    for metric in ("rmse_xy", "rmse_z")
                }
    return out


def summary_lines(budget: dict, sweep: str, sensors: str) -> list[str]:
    """A few printable lines: PD and its navigation error per (sensing, wind) cell, the wind-aware
    policy against PD, and the stationary navigation error with its headroom."""
    lines = []
    for mode, cells in budget["pd"].items():
        line = "; ".join(f"{wind}: PD xy {c['rmse_xy']:.3f} z {c['rmse_z']:.3f} m, nav error xy {c['nav_rmse_xy']:.3f} "
                         f"z {c['nav_rmse_z']:.3f} m" for wind, c in cells.items())
        if mode in budget["aware_vs_pd"]:
            aware = budget["aware_vs_pd"][mode]["rmse_xy"]
            line += f"; wind-aware vs PD xy {aware['improvement']:.1f} % (wins {aware['wins']}/{aware['n']})"
        lines.append(f"{mode:>10}: {line}")
    if "navigation" in budget["pd"] and "full" in budget["pd"]["navigation"]:
        nav = budget["pd"]["navigation"]["full"]
        lines.append(f"stationary navigation error ({sweep}, {sensors}): xy {nav['nav_rmse_xy']:.3f} m, "
                     f"z {nav['nav_rmse_z']:.3f} m; headroom xy {headroom_pct(nav['nav_rmse_xy'], nav['rmse_xy']):.0f} %, "
                     f"z {headroom_pct(nav['nav_rmse_z'], nav['rmse_z']):.0f} %")
    return lines


SENSING_LABEL = {"navigation": "as shipped (nav filter)", "no_bias": "no sensor bias", "true_state": "PD on the true state"}


def error_budget_section(budgets: dict[str, dict]) -> str:
    """Tables of ``recipes/error_budget.py``: PD RMSE per (sensing, wind) cell with its navigation
    error, and the wind-aware policy against PD in full wind under each sensing."""
    lines = ["## Error budget: what part of PD's error a controller can remove", ""]
    lines.append("Commands: " + "; ".join(f"`{b['command']}` (commit `{b.get('git_commit')}`)" for b in budgets.values())
                 + ". The same episodes flown again with the sensing idealised and the wind removed")
    lines.append("(`quadwind_trl/evaluation/error_budget.py`). *nav error* is the RMSE of the position the PD flies on")
    lines.append("against the true one, on the scored steps: error the vehicle cannot see and no controller can remove.")
    lines.append("*headroom* = 1 - nav error / PD RMSE: about the largest xy improvement any controller could reach.")
    lines.append("")
    for key, b in budgets.items():
        lines.append(f"**{b.get('sweep', key)}, sensing preset `{b.get('sensors', 'policy')}`** (`results/{key}.json`; {b['episodes']} episodes; mean RMSE in m; "
                     "- = not flown)")
        lines.append("")
        lines.append("| sensing | PD xy: full wind | mean wind only | still air | nav error xy (full) | PD z (full) | nav error z (full) |"
                     " headroom xy | headroom z | wind-aware vs PD, xy (full wind) | wins | wind-aware vs PD, z |")
        lines.append("|" + "---|" * 12)
        for mode, cells in b["pd"].items():
            full = cells["full"]
            other = {w: f"{cells[w]['rmse_xy']:.3f}" if w in cells else "-" for w in ("mean_only", "still")}
            row = (f"| {SENSING_LABEL.get(mode, mode)} | {full['rmse_xy']:.3f} | {other['mean_only']} | {other['still']} | "
                   f"{full['nav_rmse_xy']:.3f} | {full['rmse_z']:.3f} | {full['nav_rmse_z']:.3f} | "
                   f"{headroom_pct(full['nav_rmse_xy'], full['rmse_xy']):.0f} % | {headroom_pct(full['nav_rmse_z'], full['rmse_z']):.0f} % |")
            if mode in b["aware_vs_pd"]:
                xy, z = b["aware_vs_pd"][mode]["rmse_xy"], b["aware_vs_pd"][mode]["rmse_z"]
                row += f" {xy['improvement']:.1f} % ({ci(xy)}) | {xy['wins']}/{xy['n']} | {z['improvement']:.1f} % |"
            else:
                row += " - | - | - |"
            lines.append(row)
        lines.append("")
    return "\n".join(lines)


SECTION = Section.of_results("error_budget", "Error budget: what part of PD's error a controller can remove",
                             "error_budget_*.json", error_budget_section)
