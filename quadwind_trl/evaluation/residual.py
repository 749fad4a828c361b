"""What the residual policy adds on a classical base: RL against the best classical controller.

A residual policy trained on a classical base law (``--base-controller``, e.g. the disturbance
observer) is flown by the paired ablation like any policy (``recipes/ablation.py --policy ...
--blind-policy ...``, one folder per training seed, ``results/residual/<base>/seed<k>/``): its
``pd`` row is the zero residual, i.e. the base law alone, and its ``aware`` and ``trained_blind``
rows the two residuals. The classical controllers' file of the same sweep
(``results/classical/ablation_<sweep>.json``) flew the paper's PD and the base law alone on the
same episodes. This module joins the two, episode by episode, and asks of them, per seed and
across seeds (:func:`~quadwind_trl.evaluation.perception.analyse_sweep`), per wind level, per
pattern flown and per flight phase:

* what RL adds over its base (the residual against the zero residual);
* the residual against the paper's PD (the measure every other table reports);
* what the wind estimate is worth on this base (wind-aware against trained-blind residual);

and, over all episodes per seed and on both axes, the same comparisons with worst episodes and
crashes, and whether the zero residual reproduces the classical file's row of the base law
(the same law on the same episodes: to the bit where the platform and batch layout agree).
"""
from __future__ import annotations

from typing import Mapping

from .ablation import episode_table_from_json
from .perception import analyse_sweep
from .statistics import paired_summary

# comparison -> (baseline, other), positive when ``other`` tracks better; ``base`` is the zero
# residual (the residual files' ``pd`` row), ``paper_pd`` the paper's PD from the classical file
RESIDUAL_COMPARISONS = {
    "aware_vs_base": ("base", "aware"),
    "trained_blind_vs_base": ("base", "trained_blind"),
    "aware_vs_trained_blind": ("trained_blind", "aware"),
    "aware_vs_paper_pd": ("paper_pd", "aware"),
}
AXES = ("rmse_xy", "rmse_z")
# the world columns both files must agree on before their rows are paired
WORLD_COLUMNS = ("case_id", "wind_speed_ref_m_s", "turb_intensity", "trajectory")


def joined_episodes(residual: dict, classical: dict, base: str) -> dict[str, list]:
    """The residual file's episode table with its ``pd`` columns renamed ``base`` and the
    classical file's PD beside them as ``paper_pd`` (every ``pd_*`` column); a ``ValueError``
    unless both files flew the same episodes in one order and the classical file flew ``base``."""
    ours, theirs = residual["episodes_table"], classical["episodes_table"]
    for column in WORLD_COLUMNS:
        if ours.get(column) != theirs.get(column):
            raise ValueError(f"the residual file ({residual.get('sweep')}) and the classical file list other episodes "
                             f"(column {column!r} differs): pair files of one sweep")
    if base not in classical["controllers"]:
        raise ValueError(f"the classical file flew {classical['controllers']}, not the base {base!r}")
    joined = {}
    for key, values in ours.items():
        joined[f"base_{key.removeprefix('pd_')}" if key.startswith("pd_") else key] = values
    joined.update({f"paper_{key}": values for key, values in theirs.items() if key.startswith("pd_")})
    return joined


def zero_residual_check(residual: dict, classical: dict, base: str) -> dict:
    """How far the zero residual's per-episode RMSEs are from the classical file's ``base`` row:
    the largest absolute difference (m) per axis and whether every one is zero."""
    ours, theirs = residual["episodes_table"], classical["episodes_table"]
    gaps = {axis: max(abs(a - b) for a, b in zip(ours[f"pd_{axis}"], theirs[f"{base}_{axis}"])) for axis in AXES}
    return {"max_abs_diff_m": gaps, "bitwise": all(g == 0.0 for g in gaps.values()),
            "same_platform": residual.get("platform") == classical.get("platform"),
            "same_batch": residual.get("batch") == classical.get("batch")}


def _overall(table: dict[str, list], resamples: int) -> dict:
    """Per axis every comparison of :data:`RESIDUAL_COMPARISONS` over all episodes, and each
    controller's worst episode and crashes."""
    columns = episode_table_from_json(table)
    out: dict = {}
    for axis in AXES:
        out[axis] = {name: paired_summary(columns[f"{a}_{axis}"], columns[f"{b}_{axis}"], resamples=resamples)
                     for name, (a, b) in RESIDUAL_COMPARISONS.items() if {f"{a}_{axis}", f"{b}_{axis}"} <= set(columns.keys())}
        out[axis]["worst"] = {c: columns[f"{c}_{axis}"].max().item() for c in ("paper_pd", "base", "aware", "trained_blind")
                              if f"{c}_{axis}" in columns.keys()}
    out["crashed"] = {c: int(columns[f"{c}_crashed"].sum()) for c in ("paper_pd", "base", "aware", "trained_blind")
                      if f"{c}_crashed" in columns.keys()}
    return out


def analyse_residual(seeds: Mapping[str, dict], classical: dict, base: str, resamples: int = 10_000) -> dict:
    """One sweep: ``seeds`` maps each training seed to its residual ablation file (parsed),
    ``classical`` is the classical controllers' file of that sweep and ``base`` the classical
    controller the residual was trained on. JSON-ready."""
    if not seeds:
        raise ValueError("analyse_residual: no seeds given")
    joined = {seed: {**result, "episodes_table": joined_episodes(result, classical, base)} for seed, result in seeds.items()}
    analysis = analyse_sweep(joined, resamples=resamples, comparisons=RESIDUAL_COMPARISONS, shares={}, by_trajectory=True)
    analysis["base"] = base
    analysis["overall"] = {seed: _overall(r["episodes_table"], resamples) for seed, r in joined.items()}
    analysis["zero_residual"] = {seed: zero_residual_check(r, classical, base) for seed, r in seeds.items()}
    return analysis
