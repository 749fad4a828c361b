"""The headroom over the best classical base controller: how much of its tracking error any
controller, learned or not, could still remove, and where the rest comes from.

The base (by default the disturbance observer, ``dob``, the classical controller the validation
searches chose in both regimes) flies a regime's test sweep again through the error budget
(:func:`~quadwind_trl.evaluation.error_budget.error_budget`) with the sensing idealised and the
wind removed, on the same episodes as the paired ablation (the shipped policy's env config, the
law's constants from :data:`~quadwind_trl.regimes.CLASSICAL_CHOICES`). Its mean RMSE per axis
(xy, z) splits into:

* **navigation error**: the RMSE of the position the base flies on against the true one, which no
  controller can see (the floor); *headroom* = 1 - navigation error / RMSE is the most a perfect
  controller could remove;
* **still-air tracking**: the error in still air on the true state, where nothing disturbs the
  vehicle and only the cascade's own lag behind the reference is left: what reference
  feed-forward, a classical answer, could remove;
* **wind**: what the full wind adds to the still-air flight, under each sensing, and of that the
  mean wind (turbulence off) and the turbulence.

The split telescopes on the mean RMSEs, so its parts add up to the full-wind, as-shipped RMSE
exactly; in which order the cells are taken matters (RMSEs do not add), and both orders are
given: the wind on the true state with the sensing last, and the sensing in still air with the
wind last. A negative part is a measured result (an idealisation that made the flight worse),
not clipped.
"""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Callable

from tensordict import TensorDictBase

from ..config import EnvConfig
from ..estimator import EstimatorBundle
from .error_budget import WINDS, Wind, error_budget
from .section import Section
from .tables import headroom_pct
from ..regimes import CLASSICAL_CONTROLLERS, CLASSICAL_LABEL, classical_controller

BASE = "dob"  # chosen on validation in both regimes (results/base_search_<regime>.json)
# the cells the split needs: the vehicle as shipped and the base on the true state
SENSING = ("navigation", "true_state")
AXES = ("xy", "z")
# laws that read no wind estimate: flown in the error budget's PD slot by a config change alone
BASES = tuple(name for name in CLASSICAL_CONTROLLERS if "_ff" not in name)


def base_law(regime: str, base: str = BASE) -> Callable[[EnvConfig], EnvConfig]:
    """A config change that makes the env's base controller classical law ``base`` of ``regime``
    (its chosen constants; the feedback, and so the sensing, left as they are)."""
    if base not in BASES:
        raise ValueError(f"base={base!r}; allowed: {BASES} (classical laws that read no wind estimate)")
    law, _ = classical_controller(regime, base)
    return lambda cfg: replace(cfg, controller=replace(cfg.controller, **law))


def headroom(
    regime: str,
    scenarios: TensorDictBase,
    policy_path: str | Path,
    estimator: EstimatorBundle,
    base: str = BASE,
    config_override: Callable[[EnvConfig], EnvConfig] | None = None,
    winds: tuple[Wind, ...] = WINDS,
    progress: bool = False,
) -> dict:
    """The base's mean RMSE and navigation error per (sensing, wind) cell (``cells``: the error
    budget's, flown with the base's law in place of PD) and their split per axis (``split``,
    :func:`split`). ``config_override`` changes the policy's env config before the law is set
    (e.g. the short flights of a smoke run). ``winds`` must include ``"full"`` and ``"still"``."""
    missing = {"full", "still"} - set(winds)
    if missing:
        raise ValueError(f"winds={winds}: the split needs {sorted(missing)} too")
    law = base_law(regime, base)
    override = law if config_override is None else (lambda cfg: law(config_override(cfg)))
    budget = error_budget(regime, scenarios, policy_path, estimator, SENSING, override, progress=progress,
                          winds=winds, with_policy=False)
    cells = budget["pd"]  # the error budget's PD slot, flown with the base's law
    return {"base": base, "base_label": CLASSICAL_LABEL[base], "law": classical_controller(regime, base)[0],
            "episodes": budget["episodes"], "cells": cells, "split": {axis: split(cells, axis) for axis in AXES}}


def _parts(total: float, parts: dict[str, float]) -> dict[str, dict[str, float]]:
    return {name: {"rmse": value, "share_pct": 100.0 * value / total} for name, value in parts.items()}


def split(cells: dict, axis: str) -> dict:
    """One axis's split of the full-wind, as-shipped mean RMSE (module docstring), in m and in %
    of it: ``total``, ``navigation_error`` and ``headroom_pct``; ``wind_on_true_state`` (still
    air on the true state, the mean wind, the turbulence, then the sensing) and
    ``sensing_in_still_air`` (still air on the true state, the sensing in still air, then the
    wind), each part's ``rmse`` and ``share_pct``; the mean wind and turbulence appear when the
    ``mean_only`` cells were flown, else one ``wind`` part."""
    if axis not in AXES:
        raise ValueError(f"axis={axis!r}; allowed: {AXES}")
    rmse = lambda sensing, wind: cells[sensing][wind][f"rmse_{axis}"]  # noqa: E731
    total, still_air = rmse("navigation", "full"), rmse("true_state", "still")
    navigation = cells["navigation"]["full"][f"nav_rmse_{axis}"]

    def wind_parts(sensing: str) -> dict[str, float]:
        if "mean_only" not in cells[sensing]:
            return {"wind": rmse(sensing, "full") - rmse(sensing, "still")}
        return {"mean_wind": rmse(sensing, "mean_only") - rmse(sensing, "still"),
                "turbulence": rmse(sensing, "full") - rmse(sensing, "mean_only")}

    true_first = {"still_air_true_state": still_air, **wind_parts("true_state"),
                  "sensing": total - rmse("true_state", "full")}
    still_first = {"still_air_true_state": still_air, "sensing": rmse("navigation", "still") - still_air,
                   **wind_parts("navigation")}
    return {"total": total, "navigation_error": navigation, "headroom_pct": headroom_pct(navigation, total),
            "wind_on_true_state": _parts(total, true_first), "sensing_in_still_air": _parts(total, still_first)}


def summary_lines(result: dict) -> list[str]:
    """A few printable lines: each axis's RMSE, navigation floor, headroom and split."""
    lines = [f"{result.get('sweep', '')} ({result['episodes']} episodes), {result['base_label']}:"]
    for axis, s in result["split"].items():
        parts = ", ".join(f"{name} {p['rmse']:.3f} m ({p['share_pct']:.0f} %)" for name, p in s["wind_on_true_state"].items())
        lines.append(f"  {axis}: RMSE {s['total']:.3f} m, navigation error {s['navigation_error']:.3f} m, "
                     f"headroom {s['headroom_pct']:.0f} %; {parts}")
    return lines


# the parts in the order each split takes them (a results file holds its keys sorted)
ORDERS = {"wind_on_true_state": ("still_air_true_state", "wind", "mean_wind", "turbulence", "sensing"),
          "sensing_in_still_air": ("still_air_true_state", "sensing", "wind", "mean_wind", "turbulence")}
PART_LABEL = {"still_air_true_state": "still air, true state (the cascade's lag)", "mean_wind": "mean wind",
              "turbulence": "turbulence", "wind": "wind", "sensing": "navigation (sensing)"}
SENSING_LABEL = {"navigation": "as shipped (nav filter)", "true_state": "on the true state"}
WIND_LABEL = {"full": "full wind", "mean_only": "mean wind only", "still": "still air"}


def _section_for(key: str, r: dict) -> list[str]:
    lines = [f"**{r['sweep']}, `{r.get('base', BASE)}`** (`results/{key}.json`; {r['episodes']} test episodes; {r['base_label']}; "
             f"`{r['command']}` at `{r['git_commit']}`)", ""]
    winds = [w for w in WINDS if w in r["cells"]["navigation"]]
    lines.append("| sensing | " + " | ".join(f"xy: {WIND_LABEL[w]}" for w in winds) + " | "
                 + " | ".join(f"z: {WIND_LABEL[w]}" for w in winds) + " | nav error xy | nav error z | crashed (full) |")
    lines.append("|" + "---|" * (2 * len(winds) + 4))
    for sensing, cells in r["cells"].items():
        lines.append(f"| {SENSING_LABEL.get(sensing, sensing)} | "
                     + " | ".join(f"{cells[w]['rmse_xy']:.3f}" for w in winds) + " | "
                     + " | ".join(f"{cells[w]['rmse_z']:.3f}" for w in winds)
                     + f" | {cells['full']['nav_rmse_xy']:.3f} | {cells['full']['nav_rmse_z']:.3f} | {cells['full']['crashed']} |")
    lines.append("")
    xy, z = r["split"]["xy"], r["split"]["z"]
    for order, title in (("wind_on_true_state", "the wind on the true state, the sensing last"),
                         ("sensing_in_still_air", "the sensing in still air, the wind last")):
        lines += [f"Split, {title} (m, and % of the as-shipped full-wind RMSE):", "",
                  "| part | xy (m) | xy share | z (m) | z share |", "|---|---|---|---|---|"]
        for name in (n for n in ORDERS[order] if n in xy[order]):
            p, q = xy[order][name], z[order][name]
            lines.append(f"| {PART_LABEL.get(name, name)} | {p['rmse']:.3f} | {p['share_pct']:.0f} % | "
                         f"{q['rmse']:.3f} | {q['share_pct']:.0f} % |")
        lines.append(f"| **total** (as shipped, full wind) | {xy['total']:.3f} | 100 % | {z['total']:.3f} | 100 % |")
        lines.append("")
    lines.append(f"Headroom (1 - navigation error / RMSE, the most a perfect controller could remove): "
                 f"xy {xy['headroom_pct']:.0f} % ({xy['total']:.3f} m against a {xy['navigation_error']:.3f} m floor), "
                 f"z {z['headroom_pct']:.0f} % ({z['total']:.3f} m against {z['navigation_error']:.3f} m).")
    lines.append("")
    return lines


def _summary(results: dict[str, dict]) -> list[str]:
    """One row per file: each base's full-wind RMSE against the floor, and the cascade's lag."""
    lines = ["| sweep | base | xy (m) | z (m) | nav floor xy / z (m) | headroom xy / z | still-air lag, share of xy | file |",
             "|---|---|---|---|---|---|---|---|"]
    for key, r in results.items():
        xy, z = r["split"]["xy"], r["split"]["z"]
        lag = xy["wind_on_true_state"]["still_air_true_state"]["share_pct"]
        lines.append(f"| {r['sweep']} | `{r.get('base', BASE)}` | {xy['total']:.3f} | {z['total']:.3f} | "
                     f"{xy['navigation_error']:.3f} / {z['navigation_error']:.3f} | {xy['headroom_pct']:.0f} % / "
                     f"{z['headroom_pct']:.0f} % | {lag:.0f} % | `results/{key}.json` |")
    return lines + [""]


def headroom_section(results: dict[str, dict]) -> str:
    """The markdown section of ``docs/results.md`` for the headroom results (by path under
    ``results/`` without ``.json``: ``headroom_<regime>`` for the observer, and any other base's in
    ``experiments/headroom_<base>/``), sweep by sweep, the observer first, with the tables,
    commands and commits."""
    sweeps = ("horizontal", "vertical")
    order = sorted(results, key=lambda k: (sweeps.index(results[k]["sweep"]) if results[k]["sweep"] in sweeps else 2,
                                           results[k].get("base", BASE) != BASE, k))
    ordered = {key: results[key] for key in order}
    lines = ["## Headroom over the best classical controller", "",
             "The classical bases chosen on validation (the disturbance observer in both regimes; in xy, the observer",
             "with the stiffer inner loop, `dob_inner`), flown again on the test sweeps' episodes with the sensing",
             "idealised and the wind removed (`quadwind_trl/studies/headroom.py`, through the error budget). *nav error* is",
             "the error of the position it flies on, which no controller can see; still air on the true state leaves",
             "only the cascade's own lag behind the reference. The splits add up to the as-shipped full-wind RMSE; RMSEs",
             "do not add, so both orders are shown. *headroom* = 1 - navigation error / RMSE: the most a perfect",
             "controller could remove.", ""]
    lines += _summary(ordered)
    for key, r in ordered.items():
        lines += _section_for(key, r)
    return "\n".join(lines)


SECTION = Section.of_results("headroom", "Headroom over the best classical controller", "**/headroom_*.json",
                             headroom_section)
