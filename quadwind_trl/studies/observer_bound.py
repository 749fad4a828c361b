"""How much better the best classical base could cancel the wind: its disturbance observer flown
again with one idealisation at a time, on a regime's validation sweep.

The stiffer-inner-loop observer (``dob_inner``) estimates the wind's force from the accelerometer
and the modelled thrust, filters it, and cancels it in the outer loop. Each variant below removes
one thing that could limit it (the same episodes, paired):

* ``as_flown``: the law as chosen on validation (the reference every gain is over);
* ``unfiltered``: its filter off, the real accelerometer (what the filter's lag costs, or saves
  from the sensor's noise);
* ``perfect_accelerometer``: the true specific force (no noise, bias or sample-and-hold), the
  chosen filter;
* ``perfect_unfiltered``: the true specific force, unfiltered: the force the wind exerts is
  cancelled from the next control step on. Any controller that reacts to the wind at the vehicle,
  learned or not, reacts no sooner, so this is the ceiling of reactive wind information through
  the outer loop (the attitude loop's lag stays, as it does for a residual on the acceleration);
* ``true_state_unfiltered``: and every input of the law true (no navigation error: beyond any
  controller's reach, shown for scale);
* ``still_air``: the law as flown with the wind off: what cancelling every effect of the wind
  would leave, the ceiling of any wind compensation on this sensing.
* ``tilt_limit_45``: the law as flown with its commanded-tilt limit at 45 deg instead of the
  paper's 35: not information but authority, for the episodes where the wind drives the vehicle to
  its limits.

The variants that differ only in the filter fly in one batch (the filter gain is a per-row
constant, :func:`~quadwind_trl.studies.base_search.fly_candidates`).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Sequence

import torch
from tensordict import TensorDictBase

from ..config import ControllerConfig, EnvConfig
from ..evaluation.statistics import paired_summary
from ..envs.trajectories import trajectory_name
from ..regimes import classical_controller
from .base_search import CandidateResult, fly_candidates
from .error_budget import Wind, with_wind
from .section import Section

BASE = "dob_inner"  # the best classical law in xy on validation in both regimes


@dataclass(frozen=True)
class Variant:
    """One idealisation of the base law: changes to its :class:`ControllerConfig` and the wind."""

    name: str
    what: str
    controller: dict = field(default_factory=dict)
    wind: Wind = "full"


VARIANTS: tuple[Variant, ...] = (
    Variant("as_flown", "the law as chosen: the accelerometer, its chosen filter"),
    Variant("unfiltered", "the accelerometer, unfiltered", {"observer_tau_s": 0.0}),
    Variant("perfect_accelerometer", "the true specific force, the chosen filter", {"observer_reads": "true_specific_force"}),
    Variant("perfect_unfiltered", "the true specific force, unfiltered: the wind's force cancelled from the next control step",
            {"observer_reads": "true_specific_force", "observer_tau_s": 0.0}),
    Variant("true_state_unfiltered", "every input true (no navigation error), unfiltered",
            {"feedback": "truth", "observer_tau_s": 0.0}),
    Variant("still_air", "the law as flown, the wind off", {}, "still"),
    Variant("tilt_limit_45", "the law as flown, its commanded tilt limited at 45 deg instead of 35 (more authority, not information)",
            {"max_tilt_deg": 45.0}),
)
REFERENCE = "as_flown"


def base_law(regime: str, config: EnvConfig, base: str = BASE) -> ControllerConfig:
    """The regime's chosen ``base`` law on ``config``'s controller (its sensing kept)."""
    law, _ = classical_controller(regime, base)
    return replace(config.controller, **law)


def fly_variants(
    regime: str,
    scenarios: TensorDictBase,
    config: EnvConfig,
    variants: Sequence[Variant] = VARIANTS,
    *,
    base: str = BASE,
    spec_settings: dict | None = None,
    compile_step: bool = False,
    device: str = "cpu",
    progress: bool = False,
) -> dict[str, CandidateResult]:
    """Every variant of the ``base`` law flown on ``scenarios`` (their wind changed per variant),
    by name; variants that differ only in the filter share a batch (:func:`fly_candidates`)."""
    law = base_law(regime, config, base)
    flown: dict[str, CandidateResult] = {}
    for wind in dict.fromkeys(v.wind for v in variants):  # one fly_candidates per wind, in order
        members = [v for v in variants if v.wind == wind]
        results = fly_candidates(regime, [replace(law, **v.controller) for v in members], with_wind(scenarios, wind), None,
                                 base_wind_input="zero", config=config, spec_settings=spec_settings, device=device,
                                 compile_step=compile_step, progress=progress)
        flown.update({v.name: r for v, r in zip(members, results)})
    return {v.name: flown[v.name] for v in variants}


def _axis(reference: torch.Tensor, other: torch.Tensor, resamples: int) -> dict:
    s = paired_summary(reference, other, resamples=resamples)
    return {"rmse_m": s["other_mean"], "gain_pct": s["improvement"], "ci_low_pct": s["ci_low"],
            "ci_high_pct": s["ci_high"], "wins": s["wins"], "episodes": s["n"],
            "median_episode_gain_pct": float(100.0 * (1.0 - other.double() / reference.double()).median())}


def bound_rows(flown: dict[str, CandidateResult], variants: Sequence[Variant] = VARIANTS,
               resamples: int = 10_000) -> list[dict]:
    """One row per variant: its mean RMSE and its paired gain over ``as_flown`` per axis (%, with
    the bootstrap 95 % interval, wins and the median episode's gain), and its crashes."""
    if REFERENCE not in flown:
        raise ValueError(f"bound_rows: the reference variant {REFERENCE!r} was not flown; flown: {sorted(flown)}")
    ref = flown[REFERENCE]
    return [{"variant": v.name, "what": v.what, "controller": v.controller, "wind": v.wind,
             "xy": _axis(ref.rmse_xy, flown[v.name].rmse_xy, resamples),
             "z": _axis(ref.rmse_z, flown[v.name].rmse_z, resamples),
             "crashed": int(flown[v.name].crashed.sum())} for v in variants]


EPISODE_FIELDS = ("traj_id", "wind_speed_ref_m_s", "turb_intensity", "altitude_m")  # what names an episode's world


def episode_rows(scenarios: TensorDictBase, flown: dict[str, CandidateResult]) -> dict[str, list]:
    """Per validation episode: its world (:data:`EPISODE_FIELDS`) and every variant's RMSEs (m), so
    where the wind's cost lies can be read episode by episode."""
    out = {name: scenarios[name].reshape(-1).tolist() for name in EPISODE_FIELDS}
    out["traj_id"] = [trajectory_name(i) for i in out["traj_id"]]
    out["rmse_xy"] = {name: r.rmse_xy.tolist() for name, r in flown.items()}
    out["rmse_z"] = {name: r.rmse_z.tolist() for name, r in flown.items()}
    return out


def costliest_episodes(episodes: dict[str, list], k: int = 5, axis: str = "xy") -> list[dict]:
    """The ``k`` episodes where the wind costs the law most (``as_flown`` minus ``still_air``, m),
    with their world and their share of the sweep's summed cost (a negative cost counts too)."""
    flown, still = episodes[f"rmse_{axis}"][REFERENCE], episodes[f"rmse_{axis}"]["still_air"]
    cost = [a - b for a, b in zip(flown, still)]
    total = sum(cost)
    order = sorted(range(len(cost)), key=lambda i: cost[i], reverse=True)[:k]
    return [{"episode": i, **{name: episodes[name][i] for name in EPISODE_FIELDS}, "as_flown_m": flown[i],
             "still_air_m": still[i], "share_pct": 100.0 * cost[i] / total if total else float("nan")} for i in order]


def bound_table(rows: Sequence[dict]) -> str:
    """The rows as a markdown table (gains over ``as_flown``)."""
    lines = ["| variant | what it idealises | xy (m) | xy gain (95 % interval), wins | z (m) | z gain, wins | crashed |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        xy, z = r["xy"], r["z"]
        lines.append(f"| `{r['variant']}` | {r['what']} | {xy['rmse_m']:.3f} | {xy['gain_pct']:+.1f} % "
                     f"[{xy['ci_low_pct']:+.1f}, {xy['ci_high_pct']:+.1f}], {xy['wins']}/{xy['episodes']} | "
                     f"{z['rmse_m']:.3f} | {z['gain_pct']:+.1f} %, {z['wins']}/{z['episodes']} | {r['crashed']} |")
    return "\n".join(lines)


def regime_markdown(report: dict, path: str) -> list[str]:
    """One regime's results file (``report``, at ``path``) as markdown: its command and commit,
    the variants' table and the episodes where the wind costs the law most."""
    lines = [f"**{report['regime']}** ({report['episodes']} validation episodes, base `{report['base']}`; `{path}`; "
             f"`{report['command']}` at `{report['git_commit']}`, {report['platform'].get('cpu', '')})", "",
             bound_table(report["variants"]), "",
             "Where the wind costs the law most in xy (`as_flown` minus `still_air`; share of the sweep's summed cost):", "",
             "| episode | pattern | wind (m/s) | turbulence intensity | altitude (m) | as flown (m) | still air (m) | share |",
             "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {e['episode']} | {e['traj_id']} | {e['wind_speed_ref_m_s']:g} | {e['turb_intensity']:g} | "
              f"{e['altitude_m']:g} | {e['as_flown_m']:.3f} | {e['still_air_m']:.3f} | {e['share_pct']:.0f} % |"
              for e in costliest_episodes(report["per_episode"])]
    return lines + [""]


def observer_bound_section(results: dict[str, dict]) -> str:
    """The section of ``docs/results.md``: every regime's file (by path under ``results/``)."""
    lines = ["## What perfect wind cancellation would add to the best classical controller", "",
             "No training: the stiffer-inner-loop observer flown again on each regime's validation sweep with its filter",
             "off, a perfect accelerometer, the true state, the wind off and a wider tilt limit, each paired against the law as chosen on the",
             "same episodes (`quadwind_trl/studies/observer_bound.py`, `recipes/observer_bound.py`;",
             "[rl.md](rl.md#the-observers-bound-what-perfect-reactive-cancellation-would-add) reads it).", ""]
    order = sorted(results, key=lambda k: ("horizontal", "vertical").index(results[k]["regime"]))
    for key in order:
        lines += regime_markdown(results[key], f"results/{key}.json")
    return "\n".join(lines)


SECTION = Section.of_results("observer_bound", "What perfect wind cancellation would add", "**/observer_bound_*.json",
                             observer_bound_section)
