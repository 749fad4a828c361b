"""Every training seed's paired ablation side by side (``recipes/reproduce.py --full``,
``results/seeds/seed<k>/ablation_<sweep>.json``): the reduction against PD of each seed, their mean
and range, and a Student-t interval over the seeds."""
from __future__ import annotations

from ..evaluation.statistics import across_seeds
from .section import ReportContext, Section
from .tables import spread, t_cell


SEED_SWEEPS = tuple((sweep, f"rmse_{axis}", f"{label} {axis}") for sweep, label in
                    (("horizontal", "horizontal"), ("vertical", "vertical"), ("ood", "OOD")) for axis in ("xy", "z"))
# per sweep and axis, the measures reported across seeds: (key in the block, label, with wins)
SEED_MEASURES = (("aware", "wind-aware vs PD", True), ("trained_blind", "trained blind vs PD", True),
                 ("trained_perception", "perception: wind-aware vs trained blind", False))


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
            lines.append(f"| {label} | {measure} | " + " | ".join(cells) + f" | {spread(across)} | {t_cell(across)} |")
    for key, measure in (("aware", "wind-aware"), ("trained_blind", "trained blind")):
        worst = [r.get("ood", {}).get("rmse_xy", {}).get("worst", {}).get(key) for r in seeds.values()]
        if any(w is not None for w in worst):
            lines.append(f"| OOD xy | worst {measure} episode (m) | "
                         + " | ".join("-" if w is None else f"{w:.2f}" for w in worst) + " | | |")
    lines.append("")
    return "\n".join(lines)


def _render(ctx: ReportContext) -> str | None:
    return seeds_section(ctx.seeds) if ctx.seeds else None


SECTION = Section("seeds", "Across training seeds", ("results/seeds/seed*/ablation_*.json",), _render)
