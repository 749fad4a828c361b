"""What the residual policy adds on a classical base: RL against the best classical controller.

A residual policy trained on a classical base law (``--base-controller``, e.g. the disturbance
observer) is flown by the paired ablation like any policy (``recipes/ablation.py --policy ...
--blind-policy ...``, one folder per training seed, ``results/residual/<base>/seed<k>/``): its
``pd`` row is the zero residual, i.e. the base law alone, and its ``aware`` and ``trained_blind``
rows the two residuals. The classical controllers' file of the same sweep
(``results/classical/ablation_<sweep>.json``) flew the paper's PD and the base law alone on the
same episodes. This module joins the two, episode by episode, and asks of them, per seed and
across seeds (:func:`~quadwind_trl.studies.perception.analyse_sweep`), per wind level, per
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

from ..envs.trajectories import trajectory_names
from ..evaluation.ablation import episode_table_from_json
from ..evaluation.statistics import paired_summary
from ..regimes import CLASSICAL_LABEL
from .perception import analyse_sweep
from .section import ReportContext, Section
from .tables import SWEEP_TITLES, in_sweep_order, paired_cell, present, seed_cells, wind_rows

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


RESIDUAL_VALUES = {"aware_vs_base": "wind-aware residual vs its base", "trained_blind_vs_base": "trained-blind residual vs its base",
                   "aware_vs_trained_blind": "wind-aware vs trained-blind residual", "aware_vs_paper_pd": "wind-aware residual vs PD"}
#: the goal set for the method against the best classical controller: xy gain (%), share of
#: episodes won, and z no worse (an improvement >= 0)
RESIDUAL_GOAL = {"xy_pct": 25.0, "win_share": 200 / 225}


def _goal_line(sweep: str, analysis: dict) -> str:
    """Whether each seed's wind-aware residual meets :data:`RESIDUAL_GOAL` against its base (on the
    out-of-distribution sweep: a worst episode below the base's)."""
    overall = analysis["overall"]
    if sweep == "ood":
        met = [s for s, o in overall.items() if o["rmse_xy"]["worst"]["aware"] < o["rmse_xy"]["worst"]["base"]]
        return (f"Goal (worst xy episode below the base's): met by {len(met)} of {len(overall)} seeds"
                + (f" ({', '.join(met)})." if met else "."))
    met = [s for s, o in overall.items() if o["rmse_xy"]["aware_vs_base"]["improvement"] >= RESIDUAL_GOAL["xy_pct"]
           and o["rmse_xy"]["aware_vs_base"]["wins"] >= RESIDUAL_GOAL["win_share"] * o["rmse_xy"]["aware_vs_base"]["n"]
           and o["rmse_z"]["aware_vs_base"]["improvement"] >= 0.0]
    return (f"Goal (xy >= {RESIDUAL_GOAL['xy_pct']:.0f} % over the base with >= {RESIDUAL_GOAL['win_share']:.0%} of the "
            f"episodes won, z no worse): met by {len(met)} of {len(overall)} seeds" + (f" ({', '.join(met)})." if met else "."))


def _residual_table(title: str, group: str, rows: list[tuple[str, dict]], values: list[str]) -> list[str]:
    """One table of the residual section: a row per group, for each of ``values`` its seed mean
    (range) and t-interval."""
    return [title, "", f"| {group} |" + "".join(f" {RESIDUAL_VALUES[v]} | 95 % t (seeds) |" for v in values),
            "|---|" + "---|" * (2 * len(values))] + [
        f"| {key} |" + "".join(f" {seed_cells(row.get(v))} |" for v in values) for key, row in rows]


def residual_section(result: dict) -> str:
    """"The residual on the best classical base" from ``results/residual_<base>.json``
    (``recipes/residual_value.py``): per sweep and seed the residual against its base and PD on
    both axes, across seeds per wind level, pattern and flight phase, and the goal set for the method."""
    base = result["base"]
    label = CLASSICAL_LABEL.get(base, base)
    lines = [f"## The residual on the best classical base: {label}", "",
             f"Command: `{result['command']}` (commit `{result.get('git_commit')}`); it flies nothing. Policies trained with",
             f"`--base-controller {base}` (the shipped recipe otherwise), wind-aware and trained blind, one paired ablation per",
             f"seed (`results/residual/{base}/seed<k>/`), joined episode by episode with the classical controllers' file of the",
             f"sweep, which flew PD and the {label} alone on the same episodes. *Base* = the zero residual, i.e. the {label}",
             "alone; improvements are the share of the first controller's RMSE the second removes (positive: the second tracks",
             "better), per seed with the paired bootstrap 95 % interval and wins, across seeds the mean (range) and a Student-t",
             "95 % interval over the seed values.", ""]
    for sweep, analysis in in_sweep_order(result["sweeps"]):
        title = SWEEP_TITLES.get(sweep, sweep)
        lines += [f"### {title} sweep ({analysis['episodes']} episodes, seeds {', '.join(analysis['seeds'])})", "",
                  "| seed | residual vs base, xy | z | trained blind vs base, xy | aware vs trained blind, xy | residual vs PD, xy | z "
                  "| worst xy (m): PD / base / residual | crashed: PD / base / residual |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for seed, o in analysis["overall"].items():
            xy, z = o["rmse_xy"], o["rmse_z"]
            worst = " / ".join(f"{xy['worst'][c]:.2f}" for c in ("paper_pd", "base", "aware"))
            crashed = " / ".join(str(o["crashed"][c]) for c in ("paper_pd", "base", "aware"))
            lines.append(f"| {seed} | {paired_cell(xy.get('aware_vs_base'))} | {paired_cell(z.get('aware_vs_base'))} | "
                         f"{paired_cell(xy.get('trained_blind_vs_base'))} | {paired_cell(xy.get('aware_vs_trained_blind'))} | "
                         f"{paired_cell(xy.get('aware_vs_paper_pd'))} | {paired_cell(z.get('aware_vs_paper_pd'))} | "
                         f"{worst} | {crashed} |")
        lines += ["", _goal_line(sweep, analysis), ""]
        values = present(analysis["by_wind"], RESIDUAL_VALUES)
        lines += _residual_table("xy by wind level (% of the first controller's RMSE removed; seed mean (range) | 95 % t (seeds)):",
                                 "U (m/s)", wind_rows(analysis["by_wind"]), values)
        # in the library's registered order: a results file keeps its keys sorted by name
        by_pattern = analysis.get("by_trajectory", {})
        patterns = [(name, by_pattern[name]) for name in trajectory_names() if name in by_pattern]
        if patterns:
            lines += [""] + _residual_table("xy by pattern over all wind levels (seed mean (range) | 95 % t (seeds)):",
                                            "pattern", patterns, values)
        phases = [(phase, groups["all"]) for phase, groups in analysis["by_phase"].items()]
        if phases:
            lines += [""] + _residual_table("xy by flight phase over all episodes (seed mean (range) | 95 % t (seeds)):",
                                            "phase", phases, values)
        checks = analysis["zero_residual"]
        bitwise = [s for s, c in checks.items() if c["bitwise"]]
        largest = max(c["max_abs_diff_m"]["rmse_xy"] for c in checks.values())
        lines += ["", f"The zero residual against the classical file's {label} row (the same law on the same episodes): "
                      f"equal to the bit for seeds {', '.join(bitwise) or 'none'}; largest per-episode xy difference "
                      f"{largest:.2g} m.", ""]
    return "\n".join(lines)


def _render(ctx: ReportContext) -> str | None:
    """One section per base (``results/residual_<base>.json``), in file-name order."""
    results = ctx.jsons("residual_*.json")
    return "\n".join(residual_section(result) for result in results.values()) if results else None


SECTION = Section("residual", "The residual on the best classical base", ("results/residual_*.json",), _render)
