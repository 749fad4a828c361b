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

import torch
from scipy import stats
from tensordict import TensorDictBase
from torch import Tensor

from ..envs.trajectories import trajectory_name
from ..manifest import repo_relative
from . import paper
from .ablation import episode_table_from_json, feedforward_comparisons
from .phases import PHASES, phase_rmse
from .statistics import decompose, paired_summary

METRIC = "rmse_xy"  # the paper's horizontal measure, and the one Table 6 reports for the vertical regime
LEVEL = 0.95
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


def t_interval(values: Sequence[float], level: float = LEVEL) -> tuple[float, float]:
    """Student-t interval of the mean of ``values`` (n - 1 degrees of freedom); NaN with fewer
    than two values."""
    n = len(values)
    if n < 2:
        return math.nan, math.nan
    x = torch.tensor(values, dtype=torch.float64)
    half = float(stats.t.ppf(0.5 + level / 2, n - 1)) * x.std().item() / math.sqrt(n)
    return x.mean().item() - half, x.mean().item() + half


def across_seeds(per_seed: Mapping[str, float]) -> dict:
    """Seed count, mean, range and t-interval of the finite seed-level values."""
    values = [v for v in per_seed.values() if math.isfinite(v)]
    if not values:
        return {"n_seeds": 0, "mean": math.nan, "min": math.nan, "max": math.nan, "t_low": math.nan, "t_high": math.nan}
    low, high = t_interval(values)
    return {"n_seeds": len(values), "mean": sum(values) / len(values), "min": min(values), "max": max(values),
            "t_low": low, "t_high": high}


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
        low, high = t_interval(diffs)
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
