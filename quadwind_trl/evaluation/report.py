"""Render ``docs/results.md`` from the result files the recipes write (``results/*.json`` and
section files), every figure of ours beside the paper's."""
from __future__ import annotations

import json
import math
from pathlib import Path

from ..envs.trajectories import trajectory_names
from ..regimes import CLASSICAL_LABEL, SWEEP_REGIME
from . import paper
from .base_search import select_candidate
from .perception import across_seeds


def _by_number(table: dict) -> list[tuple[str, dict]]:
    """JSON object keys are strings: order wind levels numerically."""
    return sorted(table.items(), key=lambda kv: float(kv[0]))


def headroom_pct(nav_rmse: float, rmse: float) -> float:
    """``100 (1 - nav error / RMSE)``: about the largest improvement any controller could make
    (the navigation error is what the vehicle cannot see)."""
    return 100.0 * (1.0 - nav_rmse / rmse)


def wall_time(seconds: float) -> str:
    """Seconds under two minutes (a toy run is never "0 min"), minutes above."""
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.0f} min"


def _ratio(ours: float, theirs: float) -> str:
    return f"{ours / theirs:.2f}" if theirs else "-"


def pd_calibration_section(result: dict) -> str:
    """The PD baseline on the paper's sweeps, beside the paper's PD columns."""
    lines = ["## PD baseline on the paper's evaluation sweeps", ""]
    lines.append(f"Command: `{result['command']}` (commit `{result.get('git_commit')}`).")
    lines.append("RMSE against the true position, scored over each flight's pattern (after the climb for")
    lines.append("horizontal flights; the whole flight after arming for vertical ones). Ratio = ours / paper.")
    lines.append("How the cruise speed, the PD's navigation feedback, the sensor biases and the wind cap were")
    lines.append("set from these sweeps, and what each did, is in [simulator.md](simulator.md#calibrating-the-pd-baseline-against-the-paper).")
    lines.append(f"Sensing preset: `{result.get('sensors', 'legacy_walk')}`. *nav* = mean navigation error (the position the PD")
    lines.append("flies on against the true one), *headroom* = 1 - nav / ours: the largest improvement any controller could make.")
    lines.append("")
    sweeps = result["sweeps"]

    def headroom(tables: dict, group: str, key: str, axis: str = "xy") -> str:
        nav = tables.get(f"nav_rmse_{axis}")
        if nav is None:
            return "- | -"
        n = nav[group][key]["mean"] if key != "all" else nav["all"]["mean"]
        ours = tables[f"rmse_{axis}"][group][key]["mean"] if key != "all" else tables[f"rmse_{axis}"]["all"]["mean"]
        return f"{n:.3f} | {headroom_pct(n, ours):.0f} %"

    if "horizontal" in sweeps:
        tables = sweeps["horizontal"]["tables"]
        t = tables["rmse_xy"]
        lines += ["### Horizontal (225 episodes): PD RMSE by mean wind speed", "",
                  "| U (m/s) | ours mean +- std (m) | median | max | paper (m) | ratio | nav (m) | headroom |",
                  "|---|---|---|---|---|---|---|---|"]
        for key, row in _by_number(t["by_wind"]):
            ref = paper.HORIZONTAL_BY_WIND[float(key)]["pd"]
            lines.append(f"| {key} | {row['mean']:.3f} +- {row['std']:.3f} | {row['median']:.3f} | {row['max']:.2f} | {ref:.3f} | "
                         f"{_ratio(row['mean'], ref)} | {headroom(tables, 'by_wind', key)} |")
        a = t["all"]
        ref = paper.HORIZONTAL_BY_WIND["all"]["pd"]
        lines.append(f"| all | {a['mean']:.3f} +- {a['std']:.3f} | {a['median']:.3f} | {a['max']:.2f} | {ref:.3f} | "
                     f"{_ratio(a['mean'], ref)} | {headroom(tables, 'all', 'all')} |")
        lines += ["", "### Horizontal: PD RMSE by trajectory", "", "| trajectory | ours (m) | paper (m) | ratio |", "|---|---|---|---|"]
        for name, row in t["by_trajectory"].items():
            ref = paper.HORIZONTAL_BY_TRAJECTORY[name]["pd"]
            lines.append(f"| `{name}` | {row['mean']:.3f} | {ref:.3f} | {_ratio(row['mean'], ref)} |")
        lines.append("")
    if "vertical" in sweeps:
        tables = sweeps["vertical"]["tables"]
        txy, tz = tables["rmse_xy"], tables["rmse_z"]
        z_ref = paper.TRACKING_STATS["vertical_z"]["pd"][0]
        lines += ["### Vertical (144 episodes): PD horizontal (xy) RMSE by mean wind speed", "",
                  "| U_mean (m/s) | ours xy mean +- std (m) | paper xy (m) | ratio | nav xy (m) | headroom xy | ours z (m) | "
                  f"ratio z (paper {z_ref:.2f}) | nav z (m) | headroom z |", "|---|---|---|---|---|---|---|---|---|---|"]
        for key, row in _by_number(txy["by_wind"]):
            ref = paper.VERTICAL_BY_WIND[float(key)]["pd"]
            z = tz["by_wind"][key]["mean"]
            lines.append(f"| {key} | {row['mean']:.3f} +- {row['std']:.3f} | {ref:.3f} | {_ratio(row['mean'], ref)} | "
                         f"{headroom(tables, 'by_wind', key)} | {z:.3f} | {_ratio(z, z_ref)} | {headroom(tables, 'by_wind', key, 'z')} |")
        a, az = txy["all"], tz["all"]
        lines.append(f"| all | {a['mean']:.3f} +- {a['std']:.3f} | {paper.VERTICAL_BY_WIND['all']['pd']:.3f} | "
                     f"{_ratio(a['mean'], paper.VERTICAL_BY_WIND['all']['pd'])} | {headroom(tables, 'all', 'all')} | "
                     f"{az['mean']:.3f} | {_ratio(az['mean'], z_ref)} | {headroom(tables, 'all', 'all', 'z')} |")
        lines.append("")
    if "ood" in sweeps:
        t = sweeps["ood"]["tables"]["rmse_xy"]
        a = t["all"]
        lines += ["### Out of distribution (90 episodes, U = 13-15 m/s): PD", "",
                  "| U (m/s) | ours mean (m) | median | max |", "|---|---|---|---|"]
        for key, row in _by_number(t["by_wind"]):
            lines.append(f"| {key} | {row['mean']:.3f} | {row['median']:.3f} | {row['max']:.2f} |")
        lines.append(f"| all | {a['mean']:.3f} | {a['median']:.3f} | {a['max']:.2f} |")
        lines.append(f"\nPaper: PD mean {paper.OOD['pd_mean']} m, worst case {paper.OOD['pd_worst']} m "
                     f"(lawnmower); ours: mean {a['mean']:.2f} m (ratio {_ratio(a['mean'], paper.OOD['pd_mean'])}), "
                     f"worst {a['max']:.1f} m; lawnmower mean {t['by_trajectory'].get('lawnmower_h', {}).get('mean', float('nan')):.2f} m "
                     f"(paper 13.96 m).")
        lines.append("Out of distribution the PD fails in the paper's way: error rising with wind, means far above")
        lines.append("medians because a few episodes are blown off track when gusts push the upwind airspeed past")
        mower = t["by_trajectory"].get("lawnmower_h", {}).get("mean", float("nan"))
        lines.append("the 30.5 m/s a 35-degree tilt can hold. The paper's collapse is stronger (mean "
                     f"{paper.OOD['pd_mean'] / a['mean']:.1f}x ours, worst case {paper.OOD['pd_worst'] / a['max']:.1f}x, "
                     f"lawnmower {13.96 / mower:.1f}x); the paper's pattern geometry is unknown, and one 47 m")
        lines.append("episode moves a 90-episode mean by 0.5 m.")
        lines.append("")
    return "\n".join(lines)


def _pm(mean: float, std: float) -> str:
    return f"{mean:.3f} +- {std:.3f}"


def _ci(block: dict) -> str:
    """A paired bootstrap interval; "to", not a dash, since either end may be negative."""
    return f"{block['ci_low']:.1f} to {block['ci_high']:.1f}"


def _stats_row(label: str, block: dict, ref: dict | None) -> str:
    d, a = block["distribution"], block["aware"]
    ours = (f"| {label} | {a['n']} | {_pm(d['pd']['mean'], d['pd']['std'])} | {_pm(d['aware']['mean'], d['aware']['std'])} | "
            f"{a['improvement']:.1f} % ({_ci(a)}) | {a['wins']}/{a['n']} |")
    if ref is None:
        return ours + " - |"
    return ours + (f" {ref['pd'][0]:.2f} / {ref['aware'][0]:.2f}, {ref['improvement']:.1f} % "
                   f"({ref['ci'][0]:.1f}-{ref['ci'][1]:.1f}), {ref['wins']}/{ref['n']} |")


def _wind_table(block: dict, reference: dict, with_oracle: bool) -> list[str]:
    head = "| U (m/s) | PD (m) | wind-blind RL (m) | wind-aware RL (m) |" + (" oracle (m) |" if with_oracle else "")
    head += " impr. (%) | perception share (%) | paper: PD / blind / aware, impr., share |"
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    rows = dict(_by_number(block["by_wind"]))
    for key, r in rows.items():
        ref = reference.get(float(key))
        line = f"| {key} | {r['pd']:.3f} | {r['blind']:.3f} | {r['aware']:.3f} |" + (f" {r['oracle']:.3f} |" if with_oracle else "")
        line += f" {r['improvement']:.1f} | {r['perception_share']:.1f} |"
        line += (f" {ref['pd']:.3f} / {ref['blind']:.3f} / {ref['aware']:.3f}, {ref['improvement']:.1f}, {ref['perception_share']:.1f} |"
                 if ref else " - |")
        lines.append(line)
    d = block["decomposition"]
    ref = reference.get("all")
    line = f"| all | {d['pd']:.3f} | {d['blind']:.3f} | {d['aware']:.3f} |"
    if with_oracle:
        line += f" {block['distribution']['oracle']['mean']:.3f} |"
    line += f" {d['improvement']:.1f} | {d['perception_share']:.1f} |"
    line += (f" {ref['pd']:.3f} / {ref['blind']:.3f} / {ref['aware']:.3f}, {ref['improvement']:.1f}, {ref['perception_share']:.1f} |"
             if ref else " - |")
    lines.append(line)
    return lines


def perception_tables(blocks: dict[str, dict]) -> list[str]:
    """Trained-blind vs wind-aware RL per sweep and wind level (xy), beside the paper's measure
    (the share of the improvement lost by zeroing the wind inputs of the wind-aware policy)."""
    lines = ["### The value of perception between trained policies (not in the paper)", "",
             "RL trained blind is a second policy trained from scratch with its wind inputs zeroed (`--wind-input zero`)",
             "and flown that way. *Perception* = the share of its xy RMSE the wind-aware policy removes (paired, 95 % CI;",
             "positive: the estimate helps); the paper's measure zeroes the wind-aware policy's own inputs instead.", ""]
    for sweep, block in blocks.items():
        t = block["trained_perception"]
        lines += [f"{sweep.capitalize()} sweep: perception {t['improvement']:+.1f} % ({_ci(t)}), "
                  f"wind-aware better in {t['wins']}/{t['n']} episodes.", "",
                  "| U (m/s) | PD (m) | RL trained blind (m) | wind-aware RL (m) | perception (%) | wind-blind (zeroed) RL (m) | "
                  "perception share of the paper's decomposition (%) |",
                  "|---|---|---|---|---|---|---|"]
        for key, r in _by_number(block["by_wind"]):
            lines.append(f"| {key} | {r['pd']:.3f} | {r['trained_blind']:.3f} | {r['aware']:.3f} | {r['trained_perception']:+.1f} | "
                         f"{r['blind']:.3f} | {r['perception_share']:.1f} |")
        lines.append("")
    return lines


def ablation_section(results: dict[str, dict]) -> str:
    """The paper's Tables 3-6, the out-of-distribution probe and the oracle row."""
    lines = ["## Wind-aware RL against PD: the paired ablation", ""]
    runs = sorted({(r["command"], r.get("git_commit")) for r in results.values()})
    lines.append("Commands: " + "; ".join(f"`{c}` (commit `{g}`)" for c, g in runs) + ". Every controller flies the")
    lines.append("same scenarios with bitwise-identical wind fields and sensor noise. Improvement = 1 - mean RL / mean PD with a")
    lines.append("paired bootstrap 95 % interval (10,000 resamples); wins = pairs where wind-aware RL is strictly better.")
    lines.append("Wind-blind RL is the same policy with its two wind inputs zeroed; the oracle is the same policy fed the true")
    lines.append("turbulence-free mean wind (not in the paper).")
    lines += ["", "### Tracking statistics (paper Table 3)", "",
              "| regime | N | PD mean +- std (m) | wind-aware mean +- std (m) | improvement (95 % CI) | wins | paper: PD / aware, impr. (CI), wins |",
              "|---|---|---|---|---|---|---|"]
    # the paper scores the horizontal regime in xy only; its z row (files flown before every sweep
    # summarized both axes lack it) shows whether xy was bought with height
    rows = (("horizontal", "rmse_xy", "horizontal (xy)", paper.TRACKING_STATS["horizontal"]),
            ("horizontal", "rmse_z", "horizontal (z)", None),
            ("vertical", "rmse_xy", "vertical (xy)", paper.TRACKING_STATS["vertical_xy"]),
            ("vertical", "rmse_z", "vertical (z)", paper.TRACKING_STATS["vertical_z"]),
            ("ood", "rmse_xy", "out of distribution (xy)", None), ("ood", "rmse_z", "out of distribution (z)", None))
    lines += [_stats_row(label, results[sweep][metric], ref) for sweep, metric, label, ref in rows
              if metric in results.get(sweep, {})]
    if "horizontal" in results:
        h = results["horizontal"]["rmse_xy"]
        with_oracle = "oracle" in h["distribution"]
        lines += ["", "### Horizontal tracking by mean wind speed, with the decomposition (paper Table 4)", ""]
        lines += _wind_table(h, paper.HORIZONTAL_BY_WIND, with_oracle)
        lines += ["", "### Horizontal tracking by trajectory (paper Table 5)", "",
                  "| trajectory | PD (m) | wind-aware (m) | impr. (%) | perception share (%) | paper: PD / aware, impr. |",
                  "|---|---|---|---|---|---|"]
        for name, r in h["by_trajectory"].items():
            ref = paper.HORIZONTAL_BY_TRAJECTORY[name]
            lines.append(f"| `{name}` | {r['pd']:.3f} | {r['aware']:.3f} | {r['improvement']:.1f} | {r['perception_share']:.1f} | "
                         f"{ref['pd']:.3f} / {ref['aware']:.3f}, {ref['improvement']:.1f} |")
        lines += ["", "![tracking](figures/tracking_horizontal.png)", "", "![decomposition](figures/decomposition_horizontal.png)",
                  "", "![trace](figures/trace_lawnmower.png)", ""]
    if "vertical" in results:
        v = results["vertical"]
        lines += ["### Vertical regime, horizontal (xy) tracking by mean wind speed (paper Table 6)", ""]
        lines += _wind_table(v["rmse_xy"], paper.VERTICAL_BY_WIND, "oracle" in v["rmse_xy"]["distribution"])
        dz = v["rmse_z"]["decomposition"]
        lines += ["", f"Vertical axis (z): kinematic share {dz['kinematic_share']:.1f} %, perception share "
                  f"{dz['perception_share']:.1f} % (paper: 104.7 % and -4.7 %).", "",
                  "![vertical](figures/tracking_vertical.png)", "", "![vertical decomposition](figures/decomposition_vertical.png)",
                  "", "![3-D trace](figures/trace_figure8_3d.png)", ""]
    trained = {name: r["rmse_xy"] for name, r in results.items() if "trained_perception" in r["rmse_xy"]}
    if trained:
        lines += perception_tables(trained)
    if "ood" in results:
        o = results["ood"]["rmse_xy"]
        a = o["aware"]
        lines += ["### Out of distribution (U = 13-15 m/s)", "",
                  "| | PD | wind-aware RL | paper PD | paper RL |", "|---|---|---|---|---|",
                  f"| mean RMSE (m) | {o['distribution']['pd']['mean']:.2f} | {o['distribution']['aware']['mean']:.2f} | {paper.OOD['pd_mean']} | {paper.OOD['aware_mean']} |",
                  f"| median RMSE (m) | {o['median']['pd']:.2f} | {o['median']['aware']:.2f} | - | - |",
                  f"| worst episode (m) | {o['worst']['pd']:.1f} | {o['worst']['aware']:.1f} | {paper.OOD['pd_worst']} | {paper.OOD['aware_worst']} |",
                  f"| improvement | | {a['improvement']:.1f} % ({_ci(a)}) | | {paper.OOD['improvement']} % |",
                  f"| wins | | {a['wins']}/{a['n']} | | {paper.OOD['wins']}/{paper.OOD['n']} |",
                  "", "![ood](figures/ood.png)", ""]
    return "\n".join(lines)


SEED_SWEEPS = tuple((sweep, f"rmse_{axis}", f"{label} {axis}") for sweep, label in
                    (("horizontal", "horizontal"), ("vertical", "vertical"), ("ood", "OOD")) for axis in ("xy", "z"))
# per sweep and axis, the measures reported across seeds: (key in the block, label, with wins)
SEED_MEASURES = (("aware", "wind-aware vs PD", True), ("trained_blind", "trained blind vs PD", True),
                 ("trained_perception", "perception: wind-aware vs trained blind", False))


def _spread(across: dict) -> str:
    """Seed mean (range) of an :func:`~quadwind_trl.evaluation.perception.across_seeds` block."""
    return f"{across['mean']:+.1f} ({across['min']:+.1f} to {across['max']:+.1f})"


def _t_cell(across: dict) -> str:
    """The 95 % t-interval over seeds of an ``across_seeds`` block; "-" with one seed."""
    if not math.isfinite(across["t_low"]):
        return "-"
    return f"{across['t_low']:+.1f} to {across['t_high']:+.1f}"


def seeds_section(seeds: dict[str, dict[str, dict]]) -> str:
    """Every seed's paired ablation (``results/seeds/<seed>/ablation_<sweep>.json``): RMSE reduction
    against PD of the wind-aware and the trained-blind policies, and perception between them, one
    column per seed, then the mean and range over the seeds and a 95 % Student-t interval of the
    mean (a measure no seed flew is left out)."""
    lines = ["## Across training seeds", "",
             "Each seed trains its own wind-aware and trained-blind policy (`recipes/reproduce.py --full`) and flies the",
             "full paired ablation (`results/seeds/seed<k>/`); the shipped policy of each regime and kind is the median seed",
             "by validation score (`median_seed` in `recipes/reproduce.py`: the test sweeps choose nothing).",
             "RMSE reduction in % (positive = the first controller tracks better), wins in brackets; the 95 % interval is",
             "Student's t over the seed values (n - 1 degrees of freedom).", "",
             "| sweep | measure | " + " | ".join(f"seed {seed}" for seed in seeds) + " | mean (range) | 95 % t-interval |",
             "|---|---|" + "---|" * (len(seeds) + 2)]
    for sweep, metric, label in SEED_SWEEPS:
        for key, measure, with_wins in SEED_MEASURES:
            blocks = {seed: r.get(sweep, {}).get(metric, {}).get(key) for seed, r in seeds.items()}
            if not any(blocks.values()):
                continue
            cells = ["-" if b is None else f"{b['improvement']:+.1f}" + (f" ({b['wins']}/{b['n']})" if with_wins else "")
                     for b in blocks.values()]
            across = across_seeds({seed: b["improvement"] for seed, b in blocks.items() if b is not None})
            lines.append(f"| {label} | {measure} | " + " | ".join(cells) + f" | {_spread(across)} | {_t_cell(across)} |")
    for key, measure in (("aware", "wind-aware"), ("trained_blind", "trained blind")):
        worst = [r.get("ood", {}).get("rmse_xy", {}).get("worst", {}).get(key) for r in seeds.values()]
        if any(w is not None for w in worst):
            lines.append(f"| OOD xy | worst {measure} episode (m) | "
                         + " | ".join("-" if w is None else f"{w:.2f}" for w in worst) + " | | |")
    lines.append("")
    return "\n".join(lines)


# the claims the summary states, one row each: (sweep, metric, label, the paper's figure or None)
SUMMARY_CLAIMS = (
    ("horizontal", "rmse_xy", "horizontal xy", {"improvement": paper.TRACKING_STATS["horizontal"]["improvement"],
                                                "ci": paper.TRACKING_STATS["horizontal"]["ci"],
                                                "pd": paper.TRACKING_STATS["horizontal"]["pd"][0]}),
    ("vertical", "rmse_xy", "vertical xy", {"improvement": paper.TRACKING_STATS["vertical_xy"]["improvement"],
                                            "ci": paper.TRACKING_STATS["vertical_xy"]["ci"],
                                            "pd": paper.TRACKING_STATS["vertical_xy"]["pd"][0]}),
    ("vertical", "rmse_z", "vertical z", {"improvement": paper.TRACKING_STATS["vertical_z"]["improvement"],
                                          "ci": paper.TRACKING_STATS["vertical_z"]["ci"],
                                          "pd": paper.TRACKING_STATS["vertical_z"]["pd"][0]}),
    ("ood", "rmse_xy", "out of distribution xy (U = 13-15 m/s)", {"improvement": paper.OOD["improvement"], "ci": None,
                                                                  "pd": paper.OOD["pd_mean"]}),
    ("ood", "rmse_z", "out of distribution z", None),
)
#: what the best-classical column says until its controllers' rows are measured
CLASSICAL_PENDING = "being measured"


def best_classical(searches: dict[str, dict]) -> dict[str, str]:
    """``{regime: classical controller}``: the family whose kept candidate has the lowest validation
    score in the regime's search (chosen on validation flights, never on a test sweep)."""
    best = {}
    for regime, search in searches.items():
        kept = {family: select_candidate(block["candidates"], search["pd"]["crashed"])["validation_score"]
                for family, block in search["families"].items()}
        best[regime] = min(kept, key=kept.get)
    return best


def summary_rows(ablations: dict[str, dict], seeds: dict[str, dict[str, dict]], classical: dict[str, dict] | None = None,
                 searches: dict[str, dict] | None = None) -> list[dict]:
    """One row per claim of :data:`SUMMARY_CLAIMS` that the ablation files hold: episodes, PD's
    mean RMSE, the shipped policy's reduction (bootstrap interval, wins), the mean over training
    seeds with its 95 % t-interval, the paper's figure and, where its test-sweep flights exist
    (``classical``), the best classical controller on validation (:func:`best_classical`)."""
    best = best_classical(searches or {})
    rows = []
    for sweep, metric, label, ref in SUMMARY_CLAIMS:
        block = ablations.get(sweep, {}).get(metric)
        if block is None:
            continue
        aware = block["aware"]
        per_seed = {seed: r[sweep][metric]["aware"]["improvement"] for seed, r in seeds.items()
                    if metric in r.get(sweep, {})}
        rows.append({"sweep": sweep, "metric": metric, "label": label, "n": aware["n"],
                     "pd_mean": aware["baseline_mean"], "improvement": aware["improvement"],
                     "ci": (aware["ci_low"], aware["ci_high"]), "wins": aware["wins"],
                     "seeds": across_seeds(per_seed), "seed_names": sorted(per_seed), "paper": ref,
                     "classical": None})
        name = best.get(SWEEP_REGIME[sweep])
        flown = (classical or {}).get(sweep, {}).get(metric, {})
        if name in flown:
            rows[-1]["classical"] = (name, flown[name])
    return rows


def summary_section(rows: list[dict], figure: str | None = None) -> str:
    """Results at a glance: the table of :func:`summary_rows` (and its figure) before the detail."""
    lines = ["## At a glance", "",
             "RMSE reduction against the PD baseline on the paper's test sweeps, `1 - mean RL / mean PD` (positive: the",
             "wind-aware policy tracks better). *Shipped*: the shipped policy (the median training seed by validation),",
             "with its paired bootstrap 95 % interval and wins. *Seeds*: the mean over every training seed with its",
             "95 % Student-t interval. *Best classical*: of PID, wind feed-forward, the disturbance observer and L1",
             "adaptive control, the one with the best validation score in the regime, flown on the same test episodes and",
             "paired with PD there",
             "(\"being measured\" until it has flown them; section \"Against classical controllers\").", "",
             "| claim | episodes | PD RMSE, ours / paper (m) | shipped policy | seeds: mean (95 % t) | paper | best classical |",
             "|---|---|---|---|---|---|---|"]
    for row in rows:
        ref, seeds = row["paper"], row["seeds"]
        pd = f"{row['pd_mean']:.3f} / {ref['pd']:.2f}" if ref else f"{row['pd_mean']:.3f} / -"
        shipped = f"{row['improvement']:+.1f} % ({row['ci'][0]:+.1f} to {row['ci'][1]:+.1f}), {row['wins']}/{row['n']}"
        seed_cell = "-" if seeds["n_seeds"] == 0 else (
            f"{seeds['mean']:+.1f} % ({_t_cell(seeds)}), seeds {', '.join(row['seed_names'])}")
        if ref is None:
            paper_cell = "not scored"
        else:
            paper_cell = f"{ref['improvement']:+.1f} %" + (f" ({ref['ci'][0]:+.1f} to {ref['ci'][1]:+.1f})" if ref["ci"] else "")
        if row["classical"] is None:
            classical_cell = CLASSICAL_PENDING
        else:
            name, c = row["classical"]
            classical_cell = (f"{CLASSICAL_LABEL.get(name, name)}: {c['improvement']:+.1f} % "
                              f"({c['ci_low']:+.1f} to {c['ci_high']:+.1f}), {c['wins']}/{c['n']}")
        lines.append(f"| {row['label']} | {row['n']} | {pd} | {shipped} | {seed_cell} | {paper_cell} | {classical_cell} |")
    lines.append("")
    if figure:
        lines += [f"![RMSE reduction against PD per claim: shipped policy, training seeds, paper]({figure})", ""]
    return "\n".join(lines)


PERCEPTION_VALUES = {"aware_vs_trained_blind": "wind-aware vs trained blind",
                     "trained_oracle_vs_trained_blind": "oracle-trained vs trained blind"}
PERCEPTION_SHARES = {"zeroing_share": "zeroing share (ours)", "trained_share": "trained-blind share"}
SWEEP_TITLES = {"horizontal": "Horizontal", "vertical": "Vertical", "ood": "Out-of-distribution"}  # and their order


def _in_sweep_order(by_sweep: dict[str, dict]) -> list[tuple[str, dict]]:
    """A JSON object's sweeps (stored in key order) in the order of :data:`SWEEP_TITLES`."""
    return sorted(by_sweep.items(), key=lambda kv: list(SWEEP_TITLES).index(kv[0]) if kv[0] in SWEEP_TITLES else len(SWEEP_TITLES))


def _wind_rows(by_wind: dict) -> list[tuple[str, dict]]:
    """Wind levels in numeric order, then ``"all"``."""
    return _by_number({k: v for k, v in by_wind.items() if k != "all"}) + [("all", by_wind["all"])]


def _present(by_wind: dict, names) -> list[str]:
    """The measures of ``names`` some wind group of an analysed sweep holds, in that order."""
    return [name for name in names if any(row.get(name) for row in by_wind.values())]


def _seed_cells(block: dict | None) -> str:
    """Seed mean (range) and its 95 % t-interval with the seed count; "-" where no seed has it."""
    if block is None or block["across_seeds"]["n_seeds"] == 0:
        return "- | -"
    a = block["across_seeds"]
    return f"{_spread(a)} | {_t_cell(a)} ({a['n_seeds']})"


def _paired_cell(block: dict | None) -> str:
    """A paired summary: improvement (bootstrap 95 % interval), wins."""
    return "-" if block is None else f"{block['improvement']:+.1f} ({_ci(block)}), {block['wins']}/{block['n']}"


def perception_sweep_tables(analysis: dict) -> list[str]:
    """One sweep of ``results/perception_value.json``: the value of perception per wind level,
    perception's share of the gain over PD beside the paper's zeroing share, every seed over all
    episodes, and the value per flight phase."""
    by_wind = analysis["by_wind"]
    values = _present(by_wind, PERCEPTION_VALUES)
    shares = _present(by_wind, PERCEPTION_SHARES)
    title = SWEEP_TITLES.get(analysis["sweep"], analysis["sweep"])
    lines = [f"### {title} sweep ({analysis['episodes']} episodes, seeds {', '.join(analysis['seeds'])})", ""]
    if values:
        head = "| U (m/s) |" + "".join(f" {PERCEPTION_VALUES[v]}: seed mean (range) | 95 % t (seeds) | pooled episodes (95 % CI), wins |"
                                     for v in values)
        lines += ["Value of perception (% of the trained-blind policy's xy RMSE removed):", "", head,
                  "|---|" + "---|" * (3 * len(values))]
        lines += [f"| {key} |" + "".join(f" {_seed_cells(row.get(v))} | {_paired_cell((row.get(v) or {}).get('pooled'))} |"
                                        for v in values) for key, row in _wind_rows(by_wind)]
        lines.append("")
    if shares:
        head = "| U (m/s) |" + "".join(f" {PERCEPTION_SHARES[k]}: seed mean (range) | 95 % t (seeds) |" for k in shares)
        lines += ["Perception's share of the xy gain over PD (%):", "", head + " paper: zeroing share |",
                  "|---|" + "---|" * (2 * len(shares) + 1)]
        for key, row in _wind_rows(by_wind):
            ref = row.get("paper_zeroing_share")
            lines.append(f"| {key} |" + "".join(f" {_seed_cells(row.get(k))} |" for k in shares)
                         + (" - |" if ref is None else f" {ref:.1f} |"))
        lines.append("")
    if analysis.get("feedforward"):
        lines += feedforward_value_table(analysis)
    every = by_wind["all"]
    lines += ["Each seed over all episodes (paired bootstrap 95 % interval):", "",
              "| seed |" + "".join(f" {PERCEPTION_VALUES[v]} |" for v in values) + "".join(f" {PERCEPTION_SHARES[k]} |" for k in shares),
              "|---|" + "---|" * (len(values) + len(shares))]
    for seed in analysis["seeds"]:
        cells = [_paired_cell(every[v]["per_seed"].get(seed)) if every.get(v) else "-" for v in values]
        cells += ["-" if not every.get(k) or every[k]["per_seed"].get(seed) is None else f"{every[k]['per_seed'][seed]:+.1f}"
                  for k in shares]
        lines.append(f"| {seed} | " + " | ".join(cells) + " |")
    lines.append("")
    for value in _present({p: g["all"] for p, g in analysis["by_phase"].items()}, PERCEPTION_VALUES):
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
    for key, row in _wind_rows(ff["by_wind"]):
        policy = (rl.get(key) or {}).get("aware_vs_trained_blind")
        cell = "-" if policy is None else f"{policy['across_seeds']['mean']:+.1f}"
        lines.append(f"| {key} | {cell} |" + "".join(f" {_paired_cell((row.get(law) or {}).get(value))} |"
                                                    for law, value in columns))
    return lines + [""]


def perception_phase_table(analysis: dict, value: str) -> list[str]:
    """One measure of :data:`PERCEPTION_VALUES` per flight phase (``quadwind_trl/evaluation/phases.py``):
    the seed mean per wind level, and over all episodes with its intervals."""
    phases = analysis["by_phase"]
    speeds = [key for key, _ in _wind_rows(analysis["by_wind"]) if key != "all"]
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
                     + f" | {_seed_cells(every)} | {_paired_cell((every or {}).get('pooled'))} |")
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
        for sweep, analysis in _in_sweep_order(variant["sweeps"]):
            change = analysis.get("change_vs_base", {})
            for key, row in _wind_rows(analysis["by_wind"]):
                c = change.get(key)
                delta = "-" if c is None else (f"{c['change']:+.1f}" + ("" if not math.isfinite(c["t_low"])
                                                                       else f" ({c['t_low']:+.1f} to {c['t_high']:+.1f})")
                                               + f" ({len(c['seeds'])})")
                ref = row.get("paper_zeroing_share")
                lines.append(f"| `{name}` | {sweep} | {key} | {_seed_cells(row.get('aware_vs_trained_blind'))} | {delta} | "
                             f"{_seed_cells(row.get('zeroing_share'))} | {'-' if ref is None else f'{ref:.1f}'} |")
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
    for _, analysis in _in_sweep_order(result["sweeps"]):
        lines += perception_sweep_tables(analysis)
    if result.get("variants"):
        lines += perception_variants_table(result["variants"])
    lines += [f"![value of the estimate](figures/{Path(result.get('figure', 'perception_value.png')).name})", ""]
    return "\n".join(lines)


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
        f"| {key} |" + "".join(f" {_seed_cells(row.get(v))} |" for v in values) for key, row in rows]


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
    for sweep, analysis in _in_sweep_order(result["sweeps"]):
        title = SWEEP_TITLES.get(sweep, sweep)
        lines += [f"### {title} sweep ({analysis['episodes']} episodes, seeds {', '.join(analysis['seeds'])})", "",
                  "| seed | residual vs base, xy | z | trained blind vs base, xy | aware vs trained blind, xy | residual vs PD, xy | z "
                  "| worst xy (m): PD / base / residual | crashed: PD / base / residual |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for seed, o in analysis["overall"].items():
            xy, z = o["rmse_xy"], o["rmse_z"]
            worst = " / ".join(f"{xy['worst'][c]:.2f}" for c in ("paper_pd", "base", "aware"))
            crashed = " / ".join(str(o["crashed"][c]) for c in ("paper_pd", "base", "aware"))
            lines.append(f"| {seed} | {_paired_cell(xy.get('aware_vs_base'))} | {_paired_cell(z.get('aware_vs_base'))} | "
                         f"{_paired_cell(xy.get('trained_blind_vs_base'))} | {_paired_cell(xy.get('aware_vs_trained_blind'))} | "
                         f"{_paired_cell(xy.get('aware_vs_paper_pd'))} | {_paired_cell(z.get('aware_vs_paper_pd'))} | "
                         f"{worst} | {crashed} |")
        lines += ["", _goal_line(sweep, analysis), ""]
        values = _present(analysis["by_wind"], RESIDUAL_VALUES)
        lines += _residual_table("xy by wind level (% of the first controller's RMSE removed; seed mean (range) | 95 % t (seeds)):",
                                 "U (m/s)", _wind_rows(analysis["by_wind"]), values)
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


def pipeline_section(times: dict[str, dict]) -> str:
    """The wall time of each stage of ``recipes/reproduce.py --full`` (``results/pipeline_times.json``)."""
    lines = ["## Pipeline wall time on this machine", "",
             "Per stage of `python recipes/reproduce.py --full`, as each finished (stages ran over several sessions, some",
             "beside another job on the other core: the 1-minute load average at the end is given).", "",
             "| stage | wall time | finished | commit | load | note |", "|---|---|---|---|---|---|"]
    for stage, t in times.items():
        load = t.get("load_average_1min")
        lines.append(f"| {stage} | {wall_time(t['wall_time_s'])} | {t['finished']} | `{t['git_commit']}` | "
                     f"{'-' if load is None else load} | {t.get('note', '')} |")
    total = sum(t["wall_time_s"] for t in times.values())
    lines += [f"| sum of the recorded stages (more than the elapsed time when two ran at once) | {wall_time(total)} | | | | |", ""]
    return "\n".join(lines)


def training_section(manifests: dict[str, dict]) -> str:
    """Every PPO training run (from its JSON manifest): command, budget, wall time and the
    periodic deterministic evaluations against PD."""
    lines = ["## PPO training runs", "",
             "Each run's periodic evaluation flies a fixed set of held-out sweep episodes deterministically, paired with PD",
             "(`improvement` = 1 - mean RL xy RMSE / mean PD xy RMSE). Frames are policy decisions at 10 Hz (docs/rl.md).",
             "The runs' manifests are `results/policies/<run>.json`, beside the kept policy.", "",
             "| run | command | commit | decisions | wall time | evaluations: frames -> xy RMSE reduction vs PD (win rate) |",
             "|---|---|---|---|---|---|"]
    for name, m in manifests.items():
        evals = "; ".join(f"{int(e['frames']):,} -> {e['improvement_rmse_xy_pct']:+.1f} % ({e['win_rate']:.2f})"
                          for e in m.get("evals", []))
        command = "python recipes/" + m["command"].split("recipes/", 1)[-1]
        lines.append(f"| {name}{_base_note(m)} | `{command}` | `{m.get('git_commit')}` | {m['frames']:,} | "
                     f"{wall_time(m['wall_time_s'])} | {evals} |")
    lines += ["", "![learning curves](figures/learning_curves.png)", ""]
    return "\n".join(lines)


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
                row += f" {xy['improvement']:.1f} % ({_ci(xy)}) | {xy['wins']}/{xy['n']} | {z['improvement']:.1f} % |"
            else:
                row += " - | - | - |"
            lines.append(row)
        lines.append("")
    return "\n".join(lines)


TOY_PREAMBLE = """# Toy run: not the paper's results

`python recipes/reproduce.py --quick` ran every stage at toy scale (a few wind cases, flights of
seconds, 1,024 PPO decisions), to show the pipeline works end to end on your machine. Its numbers
say nothing about the method: the estimators and policies are barely trained, and each table
counts only the episodes flown here. The paper-scale results are in `docs/results.md` of the
repository (`python recipes/reproduce.py --full` remakes them, in hours).
"""


def toy_tracking_section(pd: dict | None, ablations: dict[str, dict], figures: list[Path]) -> str:
    """The toy run's tracking numbers, with the episode counts it flew and no paper columns."""
    lines = ["## Tracking (toy scale)", "",
             "RMSE reduction = 1 - mean RL / mean PD (positive: RL tracks better), paired bootstrap 95 % interval.", "",
             "| sweep | episodes | PD xy RMSE (m) | wind-aware RL xy RMSE (m) | xy RMSE reduction (95 % CI) | wins |",
             "|---|---|---|---|---|---|"]
    for name, result in ablations.items():
        block = result["rmse_xy"]
        d, a = block["distribution"], block["aware"]
        lines.append(f"| {name} | {a['n']} | {d['pd']['mean']:.3f} | {d['aware']['mean']:.3f} | "
                     f"{a['improvement']:.1f} % ({_ci(a)}) | {a['wins']}/{a['n']} |")
    if pd is not None and not ablations:
        for name, sweep in pd["sweeps"].items():
            a = sweep["tables"]["rmse_xy"]["all"]
            lines.append(f"| {name} | {a.get('n', '-')} | {a['mean']:.3f} | - | - | - |")
    lines.append("")
    lines += [f"- [{fig.stem}](figures/{fig.name})" for fig in figures]
    return "\n".join(lines + [""])


def sensing_presets_section(results: dict[str, dict]) -> str:
    """PD and its navigation error on every sweep under each sensing preset (``results``: preset
    name -> a ``recipes/pd_baseline.py`` result file flown with ``--sensors`` that preset)."""
    lines = ["## PD and navigation error under each sensing preset", "",
             "The same sweeps flown with the receiver class changed (`recipes/pd_baseline.py --sensors <preset>`);",
             "*nav* = mean navigation error, *headroom* = 1 - nav / PD. The commands and commits:", ""]
    lines += [f"* `{name}`: `{r['command']}` (commit `{r.get('git_commit')}`)" for name, r in results.items()]
    lines += ["", "| preset | sweep | PD xy (m) | nav xy (m) | headroom xy | PD z (m) | nav z (m) | headroom z |",
              "|---|---|---|---|---|---|---|---|"]
    for name, r in results.items():
        for sweep, block in r["sweeps"].items():
            t = block["tables"]
            cells = []
            for axis in ("xy", "z"):
                pd_, nav = t[f"rmse_{axis}"]["all"]["mean"], t[f"nav_rmse_{axis}"]["all"]["mean"]
                cells.append(f"{pd_:.3f} | {nav:.3f} | {headroom_pct(nav, pd_):.0f} %")
            lines.append(f"| `{name}` | {sweep} | {' | '.join(cells)} |")
    lines.append("")
    return "\n".join(lines)


FAMILY_LABEL = {"pid": "PD + integral (PID)", "dob": "PD + disturbance observer", "l1": "PD + L1 adaptive",
                "pid_ff": "PD + integral + wind feed-forward"}
FIELD_LABEL = {"ki_pos": "K_i (1/s^3)", "observer_tau_s": "tau (s)"}
POLICY_KINDS = (("wind-aware RL", "estimate"), ("trained-blind RL", "zero"), ("trained-oracle RL", "truth"))


def _searched(value) -> str:
    return f"{value[0]:g}" if isinstance(value, list) else f"{value:g}"


def _seed_stats(values: list[float]) -> str:
    return f"{sum(values) / len(values):+.1f} % ({min(values):+.1f} to {max(values):+.1f})"


def _on_pd(manifest: dict) -> bool:
    """Whether a policy's manifest trained its residual on the paper's PD (no classical addition;
    manifests older than the additions have none)."""
    controller = manifest.get("env_spec", {}).get("env_config", {}).get("controller", {})
    return controller.get("disturbance", "none") == "none" and not any(controller.get("ki_pos", ()))


def _base_note(manifest: dict) -> str:
    """For a policy trained on a classical base, what its "vs PD" figures are measured against."""
    if _on_pd(manifest):
        return ""
    controller = manifest["env_spec"]["env_config"]["controller"]
    parts = ["integral"] if any(controller.get("ki_pos", ())) else []
    parts += [{"observer": "disturbance observer", "l1": "L1 adaptive", "wind_model": "wind feed-forward"}[controller["disturbance"]]] if (
        controller.get("disturbance", "none") != "none") else []
    return f" (against its base, PD + {' + '.join(parts)})"


def classical_section(searches: dict[str, dict], manifests: dict[str, dict]) -> str:
    """"Against classical controllers": each regime's validation search
    (``results/base_search_<regime>.json``, recipes/tune_base_controllers.py), every candidate
    against PD on the validation sweep, beside the PPO seeds' own validation evaluations against
    the same PD on the same episodes (their kept policies' manifests)."""
    lines = ["## Against classical controllers", "",
             "The paper's PD has no integral action. The classical controllers a practitioner would fly (PD with integral",
             "action, a disturbance observer, L1 adaptive control, wind feed-forward on the estimate; docs/simulator.md,",
             "\"Classical base controllers\") are tuned here on each regime's validation sweep, scored as the trainer",
             "scores a policy (mean RMSE plus the mean of the worst tenth, lower is better; a family keeps its best",
             "candidate among those that crash no more often than PD). Beside them, the PPO seeds' own evaluations on the",
             "same validation episodes against the same PD (their kept checkpoints). These are validation flights, the",
             "flights choices are made on; the test sweeps' rows come from the paired ablation. A family's candidates",
             "fly in one batch, so its `K_i = 0` row is PD (or PD with feed-forward alone) in another batch layout: equal",
             "to PD to float rounding, which is all its few \"wins\" are.", ""]
    for regime, search in searches.items():
        pd = search["pd"]
        lines += [f"### {regime.capitalize()} validation sweep ({search['episodes']} episodes)", "",
                  f"`{search['command']}` at `{search['git_commit']}`, "
                  f"{'compiled' if search.get('compile_step') else 'eager'} step. PD: xy {pd['rmse_xy']:.3f} m, "
                  f"z {pd['rmse_z']:.3f} m, score {pd['validation_score']:.3f} m."]
        others = {family: block for family, block in search["families"].items()
                  if block.get("git_commit", search["git_commit"]) != search["git_commit"]}
        if others:  # families a later run flew beside the file's (the same env and episodes)
            lines.append("Flown by another run: " + "; ".join(f"{FAMILY_LABEL.get(f, f)}: `{b['command']}` at `{b['git_commit']}`"
                                                              for f, b in others.items()) + ".")
        lines += ["",
                  "| controller | searched value | score (m) | xy RMSE (m) | xy vs PD | z RMSE (m) | z vs PD | wins | crashed |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for family, block in search["families"].items():
            label = FAMILY_LABEL.get(family, family)
            kept = select_candidate(block["candidates"], pd["crashed"])
            for row in block["candidates"]:
                chosen = " **(chosen)**" if row is kept else ""
                lines.append(f"| {label} | {FIELD_LABEL.get(block['field'], block['field'])} = {_searched(row['value'])}{chosen} | "
                             f"{row['validation_score']:.3f} | {row['rmse_xy']:.3f} | {row['improvement_xy_pct']:+.1f} % | "
                             f"{row['rmse_z']:.3f} | {row['improvement_z_pct']:+.1f} % | {row['wins']}/{row['episodes']} | "
                             f"{row['crashed']} |")
        runs = {kind: [m["metrics"] for name, m in manifests.items() if name.startswith(f"ppo_{regime}") and _on_pd(m)
                       and m.get("env_spec", {}).get("wind_input") == wind and m.get("metrics")] for kind, wind in POLICY_KINDS}
        runs = {kind: ms for kind, ms in runs.items() if ms}
        if runs:
            lines += ["", "| PPO seeds (kept policies) | seeds | score (m): mean (range) | xy vs PD: mean (range) | "
                      "z vs PD: mean (range) | crashed (sum) |", "|---|---|---|---|---|---|"]
            for kind, ms in runs.items():
                scores = [m["validation_score"] for m in ms]
                lines.append(f"| {kind} | {len(ms)} | {sum(scores) / len(scores):.3f} ({min(scores):.3f} to {max(scores):.3f}) | "
                             f"{_seed_stats([m['improvement_rmse_xy_pct'] for m in ms])} | "
                             f"{_seed_stats([m['improvement_rmse_z_pct'] for m in ms])} | {sum(m['crashed'] for m in ms)} |")
        lines.append("")
    return "\n".join(lines)


def _by_wind_gain(episodes: dict, name: str) -> dict[float, float]:
    """``{wind level: xy RMSE reduction of controller name against PD, %}`` from an episode table."""
    winds = episodes["wind_speed_ref_m_s"]
    out = {}
    for level in sorted(set(winds)):
        rows = [i for i, w in enumerate(winds) if w == level]
        pd = sum(episodes["pd_rmse_xy"][i] for i in rows)
        out[level] = 100.0 * (1.0 - sum(episodes[f"{name}_rmse_xy"][i] for i in rows) / pd)
    return out


def classical_sweeps_section(classical: dict[str, dict], ablations: dict[str, dict],
                             seeds: dict[str, dict[str, dict]]) -> str:
    """The classical controllers on the test sweeps (``results/classical/ablation_<sweep>.json``,
    each paired with the PD it flew beside) next to the wind-aware policy's rows of the paired
    ablation (the shipped policy, and the seeds' range)."""
    lines = ["### On the test sweeps", "",
             "Each classical row is paired with the PD flown beside it on the same episodes (bootstrap 95 % interval);",
             "the RL rows are the paired ablation's (the shipped policy, and the mean and range of seeds 0-4), each",
             "paired with its own PD flight of the same episodes: where the files come from processors of another",
             "vector instruction set, PD's mean RMSE differs in the last digits (both are given).", ""]
    for sweep, result in _in_sweep_order(classical):
        names = [c for c in result["controllers"] if c != "pd"]
        rl = ablations.get(sweep)
        xy, z = result["rmse_xy"], result["rmse_z"]
        pd_means = f"PD xy {xy['distribution']['pd']['mean']:.3f} m here"
        if rl is not None:
            pd_means += f", {rl['rmse_xy']['distribution']['pd']['mean']:.3f} m in the RL file"
        lines += [f"#### {SWEEP_TITLES.get(sweep, sweep)} sweep ({result['episodes']} episodes)", "",
                  f"`{result['command']}` at `{result['git_commit']}`; {pd_means}.", "",
                  "| controller | xy vs PD (95 % CI) | wins | z vs PD (95 % CI) | worst xy (m) | crashed |",
                  "|---|---|---|---|---|---|"]
        for name in names:
            lines.append(f"| {CLASSICAL_LABEL.get(name, name)} | {xy[name]['improvement']:+.1f} % ({_ci(xy[name])}) | "
                         f"{xy[name]['wins']}/{xy[name]['n']} | {z[name]['improvement']:+.1f} % ({_ci(z[name])}) | "
                         f"{xy['worst'][name]:.3f} | {result['crashed'][name]} |")
        if rl is not None and "aware" in rl["rmse_xy"]:
            a, az = rl["rmse_xy"]["aware"], rl["rmse_z"]["aware"]
            lines.append(f"| wind-aware RL, shipped | {a['improvement']:+.1f} % ({_ci(a)}) | {a['wins']}/{a['n']} | "
                         f"{az['improvement']:+.1f} % ({_ci(az)}) | {rl['rmse_xy']['worst']['aware']:.3f} | "
                         f"{rl['crashed']['aware']} |")
            per_seed = [r[sweep] for r in seeds.values() if sweep in r and "aware" in r[sweep]["rmse_xy"]]
            if per_seed:
                gx = [r["rmse_xy"]["aware"]["improvement"] for r in per_seed]
                gz = [r["rmse_z"]["aware"]["improvement"] for r in per_seed]
                lines.append(f"| wind-aware RL, {len(per_seed)} seeds: mean (range) | {_seed_stats(gx)} | | "
                             f"{_seed_stats(gz)} | {max(r['rmse_xy']['worst']['aware'] for r in per_seed):.3f} (largest) | "
                             f"{sum(r['crashed']['aware'] for r in per_seed)} (sum) |")
        ff = [law for law in ("pd_ff", "pid_ff") if law in result["rmse_xy"].get("feedforward", {})]
        for law in ff:
            block = xy["feedforward"][law]
            parts = [f"{label} {block[key]['improvement']:+.1f} % ({_ci(block[key])}), {block[key]['wins']}/{block[key]['n']}"
                     for key, label in (("estimate_value", "the estimate against zero"),
                                        ("oracle_value", "the true wind against the estimate")) if key in block]
            lines += ["", f"What the estimate is worth to {CLASSICAL_LABEL[law]} (xy): " + "; ".join(parts) + "."]
        winds = _by_wind_gain(result["episodes_table"], names[0])
        lines += ["", "xy RMSE reduction against PD by wind level (m/s): | " + " | ".join(f"{w:g}" for w in winds) + " |",
                  "|---|" + "---|" * len(winds)]
        for name in names:
            gains = _by_wind_gain(result["episodes_table"], name)
            lines.append(f"| {CLASSICAL_LABEL.get(name, name)} | " + " | ".join(f"{g:+.1f} %" for g in gains.values()) + " |")
        if rl is not None and "aware" in rl["rmse_xy"]:
            gains = _by_wind_gain(rl["episodes_table"], "aware")
            lines.append("| wind-aware RL, shipped | " + " | ".join(f"{g:+.1f} %" for g in gains.values()) + " |")
        lines.append("")
    return "\n".join(lines)


def read_searches(folder: Path) -> dict[str, dict]:
    """The base-controller validation searches in ``folder``, by regime (those that exist)."""
    return {regime: json.loads((folder / f"base_search_{regime}.json").read_text())
            for regime in ("horizontal", "vertical") if (folder / f"base_search_{regime}.json").exists()}


def policy_runs(runs_dir: Path, kept_dir: Path) -> tuple[dict[str, dict], dict[str, Path]]:
    """Every PPO run by name (``ppo_horizontal_seed0``, ...): its manifest, the run's own
    ``RUNS/<name>/policy.json`` else the kept copy ``KEPT/<name>.json`` (``results/policies/``, in
    the repository), and the run directories whose logs can draw learning curves (``runs/`` is
    local: a fresh clone has the manifests but no curves)."""
    paths = {path.parent.name: path for path in sorted(runs_dir.glob("ppo_*/policy.json"))}
    for path in sorted(kept_dir.glob("ppo_*.json")):
        paths.setdefault(path.stem, path)
    manifests = {name: json.loads(paths[name].read_text()) for name in sorted(paths)}
    logged = {name: runs_dir / name for name in manifests if (runs_dir / name / "logs").exists()}
    return manifests, logged


def read_ablations(folder: Path) -> dict[str, dict]:
    """The ablation results files in ``folder``, by sweep (those that exist)."""
    return {name: json.loads((folder / f"ablation_{name}.json").read_text())
            for name in ("horizontal", "vertical", "ood") if (folder / f"ablation_{name}.json").exists()}


def read_seed_ablations(results_dir: Path) -> dict[str, dict[str, dict]]:
    """Every training seed's ablation files (``RESULTS/seeds/seed<k>/``), by seed name (``"0"``, ...)."""
    seeds = {path.name.removeprefix("seed"): read_ablations(path) for path in sorted((results_dir / "seeds").glob("seed*"))}
    return {seed: r for seed, r in seeds.items() if r}


def page_summary_rows(results_dir: Path) -> list[dict]:
    """The results page's at-a-glance rows (:func:`summary_rows`) from the files in ``results_dir``."""
    return summary_rows(read_ablations(results_dir), read_seed_ablations(results_dir),
                        read_ablations(results_dir / "classical"), read_searches(results_dir))


def build_report(results_dir: Path, sections_dir: Path, preamble: str, policy_manifests: dict[str, dict] | None = None,
                 toy: bool = False, summary_figure: str | None = None) -> str:
    """The whole results page: the preamble, the summary (with ``summary_figure``, a link relative
    to the page, when given), then every section whose inputs exist. ``toy``: the
    ``--quick`` run's page, which says so in its first line and shows only what it flew (no paper
    columns, ratios or the paper's episode counts)."""
    if toy:
        pd_file = results_dir / "pd_baseline.json"
        ablations = read_ablations(results_dir)
        parts = [TOY_PREAMBLE.rstrip(), "",
                 toy_tracking_section(json.loads(pd_file.read_text()) if pd_file.exists() else None, ablations,
                                      sorted((results_dir.parent / "figures").glob("*.png")))]
        if policy_manifests:
            parts.append(training_section(policy_manifests))
        return "\n".join(parts) + "\n"
    parts = [preamble.rstrip(), ""]
    ablations = read_ablations(results_dir)
    seeds = read_seed_ablations(results_dir)
    if ablations:
        parts.append(summary_section(page_summary_rows(results_dir), summary_figure))
    pd_file = results_dir / "pd_baseline.json"
    if pd_file.exists():
        parts.append(pd_calibration_section(json.loads(pd_file.read_text())))
    presets = {path.stem.removeprefix("pd_baseline_"): path for path in sorted(results_dir.glob("pd_baseline_*.json"))}
    if pd_file.exists() and presets:
        default = json.loads(pd_file.read_text())
        runs = {default.get("sensors", "rtk"): default} | {name: json.loads(path.read_text()) for name, path in presets.items()}
        parts.append(sensing_presets_section(runs))
    if policy_manifests:
        parts.append(training_section(policy_manifests))
    if ablations:
        parts.append(ablation_section(ablations))
    if seeds:
        parts.append(seeds_section(seeds))
    searches = read_searches(results_dir)
    if searches:
        parts.append(classical_section(searches, policy_manifests or {}))
    classical = read_ablations(results_dir / "classical")
    if classical:
        parts.append(classical_sweeps_section(classical, ablations, seeds))
    perception = results_dir / "perception_value.json"
    if perception.exists():
        parts.append(perception_section(json.loads(perception.read_text())))
    for residual in sorted(results_dir.glob("residual_*.json")):
        parts.append(residual_section(json.loads(residual.read_text())))
    times = results_dir / "pipeline_times.json"
    if times.exists():
        parts.append(pipeline_section(json.loads(times.read_text())))
    budgets = {path.stem: json.loads(path.read_text())
               for path in sorted(results_dir.glob("error_budget_*.json"))}
    if budgets:
        parts.append(error_budget_section(budgets))
    for section in sorted(sections_dir.glob("*.md")):
        parts.append(section.read_text().rstrip())
        parts.append("")
    return "\n".join(parts) + "\n"
