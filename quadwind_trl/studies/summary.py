"""Results at a glance: one row per claim of the paired ablation against PD (the shipped policy,
the training seeds, the paper and the best classical controller on validation), as the results
page's opening table and figure."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..evaluation.figures import COLORS, plt, save_figure
from ..evaluation.statistics import across_seeds
from ..regimes import CLASSICAL_LABEL, SWEEP_REGIME
from . import paper
from .base_search import select_candidate
from .section import ReportContext, Section, read_ablations, read_searches, read_seed_ablations
from .tables import t_cell


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
            f"{seeds['mean']:+.1f} % ({t_cell(seeds)}), seeds {', '.join(row['seed_names'])}")
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


def page_summary_rows(results_dir: Path) -> list[dict]:
    """The results page's at-a-glance rows (:func:`summary_rows`) from the files in ``results_dir``."""
    return summary_rows(read_ablations(results_dir), read_seed_ablations(results_dir),
                        read_ablations(results_dir / "classical"), read_searches(results_dir))


def results_summary(rows: list[dict], path: Path) -> Path:
    """The summary's claims as one chart: per claim, the RMSE reduction against PD of the shipped
    policy (paired bootstrap 95 % interval), the mean over training seeds (95 % t-interval), the
    paper's figure (its interval where it states one) and the best classical controller on
    validation where it flew the claim's sweep (paired bootstrap 95 %). Rows come from
    :func:`summary_rows`."""
    fig, a = plt.subplots(figsize=(8.5, 0.75 * len(rows) + 1.4))
    y = np.arange(len(rows))[::-1].astype(float)
    for yi, row in zip(y, rows):
        lo, hi = row["ci"]
        a.errorbar(row["improvement"], yi + 0.18, xerr=[[row["improvement"] - lo], [hi - row["improvement"]]], fmt="o",
                   color=COLORS["aware"], capsize=3, label="shipped policy (bootstrap 95 %)" if yi == y[0] else None)
        seeds = row["seeds"]
        if seeds["n_seeds"] > 1 and np.isfinite(seeds["t_low"]):
            a.errorbar(seeds["mean"], yi, xerr=[[seeds["mean"] - seeds["t_low"]], [seeds["t_high"] - seeds["mean"]]],
                       fmt="s", color="tab:cyan", capsize=3,
                       label=f"mean of {seeds['n_seeds']} training seeds (t 95 %)" if yi == y[0] else None)
        ref = row["paper"]
        if ref is not None:
            err = None if ref["ci"] is None else [[ref["improvement"] - ref["ci"][0]], [ref["ci"][1] - ref["improvement"]]]
            a.errorbar(ref["improvement"], yi - 0.18, xerr=err, fmt="D", color="k", capsize=3,
                       label="paper" if yi == y[0] else None)
        if row.get("classical") is not None:
            name, c = row["classical"]
            a.errorbar(c["improvement"], yi - 0.36, xerr=[[c["improvement"] - c["ci_low"]], [c["ci_high"] - c["improvement"]]],
                       fmt="^", color="tab:orange", capsize=3,
                       label=f"best classical on validation: {CLASSICAL_LABEL.get(name, name)} (bootstrap 95 %)"
                       if yi == y[0] else None)
    a.axvline(0.0, color="gray", lw=0.8)
    a.set_yticks(y, [f"{row['label']}\n{row['n']} episodes" for row in rows], fontsize=8)
    a.set(xlabel="RMSE reduction against PD (%; positive: tracks better than PD)",
          title="Against PD on the test sweeps: RL, the paper, the best classical controller")
    a.legend(fontsize=8, loc="upper left")
    return save_figure(fig, path)


def _render(ctx: ReportContext) -> str | None:
    if not ctx.ablations:
        return None
    rows = summary_rows(ctx.ablations, ctx.seeds, ctx.classical, ctx.searches)
    return summary_section(rows, ctx.summary_figure)


SECTION = Section("summary", "At a glance", ("results/ablation_*.json", "results/seeds/seed*/ablation_*.json",
                                             "results/classical/ablation_*.json", "results/base_search_*.json"), _render)
