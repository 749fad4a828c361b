"""What the wind estimate is worth to the controller: the paired ablation's results of
several training seeds, compared across seeds.

Per training seed the ablation (:mod:`~quadwind_trl.evaluation.ablation`) flies, on the same
episodes, a wind-aware policy, a policy trained with its wind inputs zeroed (``trained_blind``)
and, where trained, one trained on the true wind (``trained_oracle``). Per wind level and over all
episodes this module computes, per seed:

* the value of perception: the paired RMSE reduction of the wind-aware (and the oracle-trained)
  policy against the trained-blind one (:func:`~quadwind_trl.evaluation.statistics.paired_summary`:
  episode-level bootstrap 95 % interval and wins);
* perception's share of the gain over PD, two ways (:func:`~quadwind_trl.evaluation.statistics.decompose`):
  the paper's *zeroing share* (the blind step is the wind-aware policy with its wind inputs
  zeroed) and the *trained share* (the blind step is the trained-blind policy);

and across seeds the mean, the range and a Student-t interval over the seed-level values (the
seed-level interval), and the pooled comparison of the seed-averaged episodes (the
episode-level interval of the seed ensemble). Policy variants (retrained without some inputs,
another EMA time constant) are analysed the same way and compared with the base recipe on the
same seeds, by a paired t-interval over the per-seed differences. All outputs are JSON-ready.
"""
from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import torch
from tensordict import TensorDictBase
from torch import Tensor

from ..envs.trajectories import trajectory_name
from ..evaluation.ablation import episode_table_from_json, feedforward_comparisons
from ..evaluation.figures import COLORS, plt, save_figure
from ..evaluation.phases import PHASES, phase_rmse
from ..evaluation.statistics import across_seeds, decompose, paired_summary, t_interval
from ..manifest import repo_relative
from ..regimes import CLASSICAL_LABEL
from . import paper
from .section import Section
from .tables import SWEEP_TITLES, in_sweep_order, paired_cell, present, seed_cells, wind_rows

LEVEL = 0.95  # the seed-level t-intervals (evaluation.statistics.t_interval's default)
METRIC = "rmse_xy"  # the paper's horizontal measure, and the one Table 6 reports for the vertical regime
# comparison -> (baseline, other): paired on the same episodes, positive when ``other`` tracks better
COMPARISONS = {
    "aware_vs_trained_blind": ("trained_blind", "aware"),
    "trained_oracle_vs_trained_blind": ("trained_blind", "trained_oracle"),
}
# share -> the controller of the decomposition's blind step (PD -> blind -> wind-aware): the
# perception share is (blind - aware) / (PD - aware)
SHARES = {"zeroing_share": "blind", "trained_share": "trained_blind"}
# the paper's zeroing share by wind level (its Tables 4 and 6); the OOD sweep has none
PAPER_BY_WIND = {"horizontal": paper.HORIZONTAL_BY_WIND, "vertical": paper.VERTICAL_BY_WIND}


# how episodes are grouped: by their mean wind level (keyed as the ablation's ``by_wind``) or by
# the pattern they fly (keyed by its registered name)
GROUPINGS = ("wind", "trajectory")


def episode_groups(table: TensorDictBase, by: str = "wind") -> dict[str, Tensor]:
    """Episode masks per group of ``by`` (one of :data:`GROUPINGS`), in sorted order, and ``"all"``."""
    if by not in GROUPINGS:
        raise ValueError(f"by={by!r}: expected one of {', '.join(GROUPINGS)}")
    if by == "wind":
        values = table["wind_speed_ref_m_s"]
        groups = {f"{k:g}": values == k for k in values.unique(sorted=True).tolist()}
    else:
        values = table["traj_id"]
        groups = {trajectory_name(k): values == k for k in values.unique(sorted=True).tolist()}
    groups["all"] = torch.ones_like(values, dtype=torch.bool)
    return groups


def _finite(columns: Sequence[Tensor], mask: Tensor) -> list[Tensor] | None:
    """The per-episode ``columns`` on the episodes of ``mask`` where all are finite (a phase RMSE
    is NaN where the episode has no sample in the phase); None where no episode is left."""
    keep = mask.clone()
    for column in columns:
        keep &= column.isfinite()
    return [column[keep] for column in columns] if bool(keep.any()) else None


def seed_values(table: TensorDictBase, column: str = METRIC, resamples: int = 10_000,
                comparisons: Mapping[str, tuple[str, str]] = COMPARISONS,
                shares: Mapping[str, str] = SHARES, by: str = "wind") -> dict[str, dict]:
    """One seed's episode table: per group of :func:`episode_groups` (``by``), the paired summary
    of every comparison (default :data:`COMPARISONS`) and every share (default :data:`SHARES`)
    whose controllers it flew, on ``<controller>_<column>`` (None where no episode of the group
    has them all finite)."""
    keys = set(table.keys())
    out: dict[str, dict] = {}
    for group, mask in episode_groups(table, by).items():
        row = {}
        for name, (baseline, other) in comparisons.items():
            columns = [f"{baseline}_{column}", f"{other}_{column}"]
            if set(columns) <= keys:
                pair = _finite([table[c] for c in columns], mask)
                row[name] = None if pair is None else paired_summary(*pair, resamples=resamples)
        for name, blind in shares.items():
            columns = [f"{c}_{column}" for c in ("pd", blind, "aware")]
            if set(columns) <= keys:
                steps = _finite([table[c] for c in columns], mask)
                row[name] = None if steps is None else decompose(*steps).perception_share
        out[group] = row
    return out


def _pooled(tables: Mapping[str, TensorDictBase], baseline: str, other: str, mask: Tensor, resamples: int) -> dict | None:
    """:func:`paired_summary` of the seed-averaged episodes: each episode's RMSE averaged over the
    seeds that flew both controllers (the episode-level interval of the seed ensemble)."""
    flew = [t for t in tables.values() if {baseline, other} <= set(t.keys())]
    if not flew:
        return None
    pair = _finite([torch.stack([t[c] for t in flew]).double().mean(0) for c in (baseline, other)], mask)
    return None if pair is None else paired_summary(*pair, resamples=resamples)


def _check_same_episodes(tables: Mapping[str, TensorDictBase]) -> None:
    """Seeds are compared episode by episode: every table must list the same cases in one order."""
    reference_seed, reference = next(iter(tables.items()))
    for seed, table in tables.items():
        if table.batch_size != reference.batch_size or not torch.equal(table["case_id"], reference["case_id"]):
            raise ValueError(f"seed {seed}'s episode table lists other episodes than seed {reference_seed}'s "
                             f"({table.batch_size[0]} vs {reference.batch_size[0]} episodes): the seeds must fly the same sweep")


def summarise_column(tables: Mapping[str, TensorDictBase], column: str, resamples: int = 10_000,
                     comparisons: Mapping[str, tuple[str, str]] = COMPARISONS,
                     shares: Mapping[str, str] = SHARES, by: str = "wind") -> dict:
    """Per group of :func:`episode_groups` (``by``): for each comparison its per-seed summaries,
    the seed-level statistics of their improvements (:func:`across_seeds`) and the pooled summary;
    for each share its per-seed values and their seed-level statistics."""
    per_seed = {seed: seed_values(table, column, resamples, comparisons, shares, by) for seed, table in tables.items()}
    groups = episode_groups(next(iter(tables.values())), by)
    out: dict[str, dict] = {}
    for group, mask in groups.items():
        row = {}
        for name, (baseline, other) in comparisons.items():
            seeds = {s: v[group][name] for s, v in per_seed.items() if v[group].get(name) is not None}
            if seeds:
                row[name] = {"per_seed": seeds,
                             "across_seeds": across_seeds({s: b["improvement"] for s, b in seeds.items()}),
                             "pooled": _pooled(tables, f"{baseline}_{column}", f"{other}_{column}", mask, resamples)}
        for name in shares:
            seeds = {s: v[group][name] for s, v in per_seed.items() if v[group].get(name) is not None}
            if seeds:
                row[name] = {"per_seed": seeds, "across_seeds": across_seeds(seeds)}
        out[group] = row
    return out


def _with_paper(by_group: dict, sweep: str) -> dict:
    """Each group's row with the paper's zeroing share beside it (None where the paper has none)."""
    reference = PAPER_BY_WIND.get(sweep, {})
    for group, row in by_group.items():
        ref = reference.get("all" if group == "all" else float(group))
        row["paper_zeroing_share"] = None if ref is None else ref["perception_share"]
    return by_group


def with_phase_rmse(table: TensorDictBase) -> TensorDictBase:
    """``table`` with ``<controller>_rmse_xy_<phase>`` (NaN where the episode has no sample in the
    phase) beside every pair of phase columns the ablation recorded."""
    for key in [k for k in table.keys() if "_sse_xy_" in k]:
        controller, phase = key.split("_sse_xy_")
        table[f"{controller}_{METRIC}_{phase}"] = phase_rmse(table[key], table[f"{controller}_samples_{phase}"]).float()
    return table


def analyse_sweep(results: Mapping[str, dict], resamples: int = 10_000,
                  comparisons: Mapping[str, tuple[str, str]] = COMPARISONS, shares: Mapping[str, str] = SHARES,
                  by_trajectory: bool = False) -> dict:
    """The value of perception on one sweep from each seed's ablation results file (``seed ->
    the parsed ablation_<sweep>.json``): per wind level and ``"all"`` (:func:`summarise_column`
    on :data:`METRIC`, the paper's zeroing share beside), per flight phase where the files
    hold phase columns (``<controller>_sse_xy_<phase>`` and ``_samples_<phase>``, :mod:`~quadwind_trl.evaluation.phases`)
    and, with ``by_trajectory``, per pattern flown. Other ``comparisons`` and ``shares`` ask other
    questions of the same files."""
    if not results:
        raise ValueError("analyse_sweep: no seeds given")
    sweeps = {r["sweep"] for r in results.values()}
    if len(sweeps) > 1:
        raise ValueError(f"analyse_sweep: the results are of several sweeps {sorted(sweeps)}; one at a time")
    sweep = sweeps.pop()
    tables = {seed: with_phase_rmse(episode_table_from_json(r["episodes_table"])) for seed, r in results.items()}
    _check_same_episodes(tables)
    keys = set().union(*(t.keys() for t in tables.values()))
    phases = [p for p in PHASES if f"aware_{METRIC}_{p}" in keys]
    by_wind = summarise_column(tables, METRIC, resamples, comparisons, shares)
    if "zeroing_share" in shares:  # the paper's own measure, beside ours
        by_wind = _with_paper(by_wind, sweep)
    analysis = {
        "sweep": sweep,
        "metric": METRIC,
        "level": LEVEL,
        "seeds": list(results),
        "episodes": next(iter(tables.values())).batch_size[0],
        "by_wind": by_wind,
        "by_phase": {p: summarise_column(tables, f"{METRIC}_{p}", resamples, comparisons, shares) for p in phases},
        # how much of a flight each phase is: the wind-aware policy's samples, per episode and seed
        "phase_samples_per_episode": {
            p: torch.cat([t[f"aware_samples_{p}"] for t in tables.values() if f"aware_samples_{p}" in t.keys()]).double().mean().item()
            for p in phases if f"aware_samples_{p}" in keys},
    }
    if by_trajectory:
        analysis["by_trajectory"] = summarise_column(tables, METRIC, resamples, comparisons, shares, by="trajectory")
    return analysis


def feedforward_by_wind(classical: dict, seeds: Mapping[str, dict] | None = None, resamples: int = 10_000) -> dict:
    """What the estimate is worth to the wind feed-forward laws (no learning) on one sweep, from
    the classical controllers' results file (``results/classical/ablation_<sweep>.json``): per
    group of :func:`episode_groups`, ``{law: {value: paired summary}}`` for each comparison of
    :func:`~quadwind_trl.evaluation.ablation.feedforward_comparisons`, on :data:`METRIC`.
    Given the seeds' results files of the same sweep, checks that the file flew their episodes."""
    table = episode_table_from_json(classical["episodes_table"])
    if seeds:
        reference = episode_table_from_json(next(iter(seeds.values()))["episodes_table"])
        _check_same_episodes({"classical": table, "seeds": reference})
    comparisons = feedforward_comparisons(classical["controllers"])
    flat = seed_values(table, METRIC, resamples, {f"{law}/{value}": pair for (law, value), pair in comparisons.items()}, {})
    out: dict[str, dict] = {}
    for group, row in flat.items():
        for law, value in comparisons:
            out.setdefault(group, {}).setdefault(law, {})[value] = row[f"{law}/{value}"]
    return out


def variant_change(base: dict, variant: dict, comparison: str = "aware_vs_trained_blind") -> dict:
    """Per wind group of two :func:`analyse_sweep` results (the base recipe's seeds and a
    variant's): the variant's value of ``comparison`` minus the base's on the seeds both trained,
    with a paired t-interval over those seeds (positive: the variant makes perception worth more).
    Paired by seed, not two independent sets: a variant may keep the base seed's policies (an EMA
    time constant retrains only the wind-aware one), and seeds the variant lacks would otherwise
    weigh on one side only."""
    out = {}
    for group, row in variant["by_wind"].items():
        if comparison not in row or comparison not in base["by_wind"].get(group, {}):
            continue
        v, b = row[comparison]["per_seed"], base["by_wind"][group][comparison]["per_seed"]
        seeds = [seed for seed in v if seed in b]
        if not seeds:
            continue
        diffs = [v[seed]["improvement"] - b[seed]["improvement"] for seed in seeds]
        low, high = t_interval(diffs, LEVEL)
        out[group] = {"seeds": seeds, "base_mean": sum(b[seed]["improvement"] for seed in seeds) / len(seeds),
                      "variant_mean": sum(v[seed]["improvement"] for seed in seeds) / len(seeds),
                      "change": sum(diffs) / len(diffs), "t_low": low, "t_high": high}
    return out


def seed_files(folder: Path, sweep: str) -> dict[str, Path]:
    """``seed -> FOLDER/seed<k>/ablation_<sweep>.json`` for the seeds that have it, by seed number."""
    found = {path.parent.name.removeprefix("seed"): path for path in folder.glob(f"seed*/ablation_{sweep}.json")
             if re.fullmatch(r"seed\d+", path.parent.name)}
    return dict(sorted(found.items(), key=lambda kv: int(kv[0])))


def read_seeds(folder: Path, sweep: str) -> tuple[dict[str, dict], dict[str, dict]]:
    """The parsed results files of :func:`seed_files`, and what each is (path, the commit that flew
    it, its policies) for the provenance record."""
    results, read = {}, {}
    for seed, path in seed_files(folder, sweep).items():
        results[seed] = json.loads(path.read_text())
        # every policy the file names (policy, blind_policy, and whatever names the oracle-trained one)
        policies = {key: value for key, value in results[seed].items() if key.endswith("policy")}
        read[seed] = {"file": repo_relative(path), "git_commit": results[seed].get("git_commit"),
                      "controllers": results[seed].get("controllers"), **policies}
    return results, read


# --- the figure --------------------------------------------------------------------------------


# the series of the perception-value figure: (key in an analysed wind group, label, colour)
FIGURE_VALUES = (("aware_vs_trained_blind", "wind-aware vs trained blind", COLORS["aware"]),
                     ("trained_oracle_vs_trained_blind", "oracle-trained vs trained blind", COLORS["oracle"]))
FIGURE_SHARES = (("zeroing_share", "zeroing share (ours)", COLORS["blind"]),
                     ("trained_share", "trained-blind share (ours)", COLORS["trained_blind"]))


def _seed_series(a, speeds: np.ndarray, blocks: list[dict | None], values, label: str, color: str, offset: float) -> None:
    """Seed dots and the seed mean with its t-interval, at each wind speed (``blocks``: one
    ``{"per_seed", "across_seeds"}`` per speed or None; ``values``: per_seed -> the seed values)."""
    have = [i for i, b in enumerate(blocks) if b is not None]
    if not have:
        return
    x = speeds[have] + offset
    for xi, i in zip(x, have):
        seeds = values(blocks[i]["per_seed"])
        a.scatter(np.full(len(seeds), xi), seeds, s=12, color=color, alpha=0.45, lw=0)
    across = [blocks[i]["across_seeds"] for i in have]
    mean = np.array([s["mean"] for s in across])
    low = np.nan_to_num(mean - np.array([s["t_low"] for s in across]))  # one seed: no bar
    high = np.nan_to_num(np.array([s["t_high"] for s in across]) - mean)
    n = sorted({s["n_seeds"] for s in across})
    a.errorbar(x, mean, yerr=[low, high], fmt="o-", color=color, capsize=3,
               label=f"{label} (n = {'/'.join(str(k) for k in n)} seeds)")


VARIANT_COLORS = ("#8c564b", "#e377c2", "#17becf", "#bcbd22")  # one per policy variant, in the order given


def perception_value(analyses: dict[str, dict], path: Path, variants: dict[str, dict] | None = None) -> Path:
    """The value of the wind estimate per wind speed, one row per sweep (:func:`analyse_sweep` results): (a) the RMSE reduction of the wind-aware and
    the oracle-trained policy against the trained-blind one; (b) perception's share of the gain
    over PD, with the trained-blind policy as the blind step and by zeroing the wind inputs, beside
    the paper's zeroing share. Each of ``variants`` (name -> ``{"sweeps": {sweep: analysis}}``, the
    policies retrained another way) adds its wind-aware-vs-trained-blind value to (a) and its
    zeroing share to (b). Dots: seeds; markers and bars: seed mean and 95 % t-interval."""
    variants = variants or {}
    fig, ax = plt.subplots(len(analyses), 2, figsize=(11, 4.0 * len(analyses)), squeeze=False)
    for (a, b), (sweep, result) in zip(ax, analyses.items()):
        rows = {float(k): v for k, v in result["by_wind"].items() if k != "all"}
        speeds = np.array(sorted(rows))
        # (key, label, colour, rows) per series; a variant's rows are its own analysis of this sweep
        extra = [(name, VARIANT_COLORS[k % len(VARIANT_COLORS)],
                  {float(u): row for u, row in variant["sweeps"][sweep]["by_wind"].items() if u != "all"})
                 for k, (name, variant) in enumerate(variants.items()) if sweep in variant["sweeps"]]
        values = [(key, label, color, rows) for key, label, color in FIGURE_VALUES]
        values += [("aware_vs_trained_blind", f"{name}: wind-aware vs trained blind", color, r) for name, color, r in extra]
        shares = [(key, label, color, rows) for key, label, color in FIGURE_SHARES]
        shares += [("zeroing_share", f"{name}: zeroing share", color, r) for name, color, r in extra]
        for panel, series, per_seed in ((a, values, lambda ps: [v["improvement"] for v in ps.values()]),
                                        (b, shares, lambda ps: list(ps.values()))):
            step = 0.5 / max(len(series), 1) * (np.diff(speeds).min() if len(speeds) > 1 else 1.0)
            for k, (key, label, color, r) in enumerate(series):
                _seed_series(panel, speeds, [r.get(u, {}).get(key) for u in speeds], per_seed, label, color,
                             (k - (len(series) - 1) / 2) * step)
        a.axhline(0, color="k", lw=0.8)
        a.set(xlabel="mean wind U (m/s)", ylabel="RMSE reduction vs trained blind (%)",
              title=f"{sweep}: value of perception, xy (positive: the wind input helps)")
        paper_share = [rows[s].get("paper_zeroing_share") for s in speeds]
        if any(p is not None for p in paper_share):
            b.plot(speeds, [np.nan if p is None else p for p in paper_share], "kx--", ms=8, label="paper: zeroing share")
        b.axhline(0, color="k", lw=0.8)
        b.set(xlabel="mean wind U (m/s)", ylabel="perception share of the gain over PD (%)",
              title=f"{sweep}: share of the improvement over PD")
        for panel in (a, b):
            panel.grid(alpha=0.3)
            panel.legend(fontsize=8)
    return save_figure(fig, path)


# --- the section --------------------------------------------------------------------------------


PERCEPTION_VALUES = {"aware_vs_trained_blind": "wind-aware vs trained blind",
                     "trained_oracle_vs_trained_blind": "oracle-trained vs trained blind"}
PERCEPTION_SHARES = {"zeroing_share": "zeroing share (ours)", "trained_share": "trained-blind share"}


def perception_sweep_tables(analysis: dict) -> list[str]:
    """One sweep of ``results/perception_value.json``: the value of perception per wind level,
    perception's share of the gain over PD beside the paper's zeroing share, every seed over all
    episodes, and the value per flight phase."""
    by_wind = analysis["by_wind"]
    values = present(by_wind, PERCEPTION_VALUES)
    shares = present(by_wind, PERCEPTION_SHARES)
    title = SWEEP_TITLES.get(analysis["sweep"], analysis["sweep"])
    lines = [f"### {title} sweep ({analysis['episodes']} episodes, seeds {', '.join(analysis['seeds'])})", ""]
    if values:
        head = "| U (m/s) |" + "".join(f" {PERCEPTION_VALUES[v]}: seed mean (range) | 95 % t (seeds) | pooled episodes (95 % CI), wins |"
                                     for v in values)
        lines += ["Value of perception (% of the trained-blind policy's xy RMSE removed):", "", head,
                  "|---|" + "---|" * (3 * len(values))]
        lines += [f"| {key} |" + "".join(f" {seed_cells(row.get(v))} | {paired_cell((row.get(v) or {}).get('pooled'))} |"
                                        for v in values) for key, row in wind_rows(by_wind)]
        lines.append("")
    if shares:
        head = "| U (m/s) |" + "".join(f" {PERCEPTION_SHARES[k]}: seed mean (range) | 95 % t (seeds) |" for k in shares)
        lines += ["Perception's share of the xy gain over PD (%):", "", head + " paper: zeroing share |",
                  "|---|" + "---|" * (2 * len(shares) + 1)]
        for key, row in wind_rows(by_wind):
            ref = row.get("paper_zeroing_share")
            lines.append(f"| {key} |" + "".join(f" {seed_cells(row.get(k))} |" for k in shares)
                         + (" - |" if ref is None else f" {ref:.1f} |"))
        lines.append("")
    if analysis.get("feedforward"):
        lines += feedforward_value_table(analysis)
    every = by_wind["all"]
    lines += ["Each seed over all episodes (paired bootstrap 95 % interval):", "",
              "| seed |" + "".join(f" {PERCEPTION_VALUES[v]} |" for v in values) + "".join(f" {PERCEPTION_SHARES[k]} |" for k in shares),
              "|---|" + "---|" * (len(values) + len(shares))]
    for seed in analysis["seeds"]:
        cells = [paired_cell(every[v]["per_seed"].get(seed)) if every.get(v) else "-" for v in values]
        cells += ["-" if not every.get(k) or every[k]["per_seed"].get(seed) is None else f"{every[k]['per_seed'][seed]:+.1f}"
                  for k in shares]
        lines.append(f"| {seed} | " + " | ".join(cells) + " |")
    lines.append("")
    for value in present({p: g["all"] for p, g in analysis["by_phase"].items()}, PERCEPTION_VALUES):
        lines += perception_phase_table(analysis, value)
    return lines


FEEDFORWARD_VALUES = {"estimate_value": "the estimate against zero", "oracle_value": "the true wind against the estimate"}


def feedforward_value_table(analysis: dict) -> list[str]:
    """The estimate's worth to the wind feed-forward laws per wind level (the classical
    controllers' file, ``analysis["feedforward"]``) beside the policies' value of perception."""
    ff = analysis["feedforward"]
    laws = sorted({law for row in ff["by_wind"].values() for law in row})
    columns = [(law, value) for law in laws for value in FEEDFORWARD_VALUES if any(
        (row.get(law) or {}).get(value) for row in ff["by_wind"].values())]
    rl = analysis["by_wind"]
    lines = ["The same question asked of a law that cannot learn: wind feed-forward (the airframe's drag model on the",
             f"estimate) against its blind twin, and the true mean wind against the estimate (`{ff['file']}`, flown at",
             f"`{ff['git_commit']}`; % of the first law's xy RMSE the second removes, paired bootstrap 95 % interval, wins),",
             "beside the policies' value of perception (seed mean) from the table above:", "",
             "| U (m/s) | wind-aware vs trained blind RL |" + "".join(
                 f" {CLASSICAL_LABEL.get(law, law)}: {FEEDFORWARD_VALUES[value]} |" for law, value in columns),
             "|---|---|" + "---|" * len(columns)]
    for key, row in wind_rows(ff["by_wind"]):
        policy = (rl.get(key) or {}).get("aware_vs_trained_blind")
        cell = "-" if policy is None else f"{policy['across_seeds']['mean']:+.1f}"
        lines.append(f"| {key} | {cell} |" + "".join(f" {paired_cell((row.get(law) or {}).get(value))} |"
                                                    for law, value in columns))
    return lines + [""]


def perception_phase_table(analysis: dict, value: str) -> list[str]:
    """One measure of :data:`PERCEPTION_VALUES` per flight phase (``quadwind_trl/evaluation/phases.py``):
    the seed mean per wind level, and over all episodes with its intervals."""
    phases = analysis["by_phase"]
    speeds = [key for key, _ in wind_rows(analysis["by_wind"]) if key != "all"]
    samples = analysis.get("phase_samples_per_episode", {})
    lines = [f"{PERCEPTION_VALUES[value].capitalize()} by flight phase (% of the trained-blind policy's xy RMSE in the phase"
             " removed; seed means per U):", "",
             "| phase | samples per episode |" + "".join(f" U = {u} |" for u in speeds)
             + " all: seed mean (range) | 95 % t (seeds) | pooled episodes (95 % CI), wins |",
             "|---|---|" + "---|" * (len(speeds) + 3)]
    for phase, groups in phases.items():
        count = samples.get(phase)
        cells = ["-" if not groups.get(u, {}).get(value) else f"{groups[u][value]['across_seeds']['mean']:+.1f}" for u in speeds]
        every = groups["all"].get(value)
        lines.append(f"| {phase} | {'-' if count is None else f'{count:.0f}'} | " + " | ".join(cells)
                     + f" | {seed_cells(every)} | {paired_cell((every or {}).get('pooled'))} |")
    return lines + [""]


def perception_variants_table(variants: dict) -> list[str]:
    """Each policy variant's value of perception per wind level, its change against the base
    recipe's same seeds with a paired t-interval, and its zeroing share beside the paper's."""
    lines = ["### Policy variants: which change makes perception matter", "",
             "Each variant retrains the wind-aware policy with one change, and the trained-blind one too where the change",
             "touches it (an EMA time constant does not: it filters an input the trained-blind policy never sees), and flies the same",
             "paired ablation. *Change* = the variant's value minus the base recipe's on the same seeds (positive: the estimate",
             "is worth more to the variant), with a paired 95 % t-interval over those seeds and their count.", "",
             "| variant | sweep | U (m/s) | wind-aware vs trained blind: seed mean (range) | 95 % t (seeds) | change vs base, same seeds (95 % paired t) "
             "| zeroing share: seed mean (range) | 95 % t (seeds) | paper: zeroing share |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, variant in variants.items():
        for sweep, analysis in in_sweep_order(variant["sweeps"]):
            change = analysis.get("change_vs_base", {})
            for key, row in wind_rows(analysis["by_wind"]):
                c = change.get(key)
                delta = "-" if c is None else (f"{c['change']:+.1f}" + ("" if not math.isfinite(c["t_low"])
                                                                       else f" ({c['t_low']:+.1f} to {c['t_high']:+.1f})")
                                               + f" ({len(c['seeds'])})")
                ref = row.get("paper_zeroing_share")
                lines.append(f"| `{name}` | {sweep} | {key} | {seed_cells(row.get('aware_vs_trained_blind'))} | {delta} | "
                             f"{seed_cells(row.get('zeroing_share'))} | {'-' if ref is None else f'{ref:.1f}'} |")
    return lines + [""]


def perception_section(result: dict) -> str:
    """The section "What the estimate is worth" from ``results/perception_value.json``
    (``recipes/perception_value.py``)."""
    flown = sorted({f"`{read['git_commit']}`" for sweep in result["inputs"]["base"].values() for read in sweep.values()})
    lines = ["## What the estimate is worth", "",
             f"Command: `{result['command']}` (commit `{result.get('git_commit')}`); it flies nothing and reads every seed's paired",
             f"ablation (`results/seeds/seed<k>/`, flown at {', '.join(flown)}). On the same episodes, the wind-aware policy and one",
             "trained from scratch with its wind inputs zeroed (*trained blind*), and where trained one fed the true mean wind",
             "in training and flight (*oracle-trained*). *Value* = the share of the trained-blind policy's xy RMSE the other",
             "removes (positive: the wind input helps): per seed with its paired bootstrap 95 % interval; across seeds the mean,",
             "range and a Student-t 95 % interval over the seed values (seed-level); *pooled* = the seed-averaged RMSE of each",
             "episode, paired, with its bootstrap 95 % interval (episode-level, the seeds held fixed). *Zeroing share* is the",
             "paper's measure: the share of the gain over PD lost when the wind-aware policy's own wind inputs are zeroed;",
             "the *trained-blind share* puts the trained-blind policy in that place (what a policy that never had the estimate",
             "loses).", ""]
    for _, analysis in in_sweep_order(result["sweeps"]):
        lines += perception_sweep_tables(analysis)
    if result.get("variants"):
        lines += perception_variants_table(result["variants"])
    lines += [f"![value of the estimate](figures/{Path(result.get('figure', 'perception_value.png')).name})", ""]
    return "\n".join(lines)


SECTION = Section.of_results("perception", "What the estimate is worth", "perception_value.json", perception_section)
