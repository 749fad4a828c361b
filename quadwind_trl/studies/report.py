"""Render ``docs/results.md``: the registered sections, in page order, each rendered by its study
from the result files the recipes wrote (:mod:`quadwind_trl.studies.section`; ``recipes/report.py``).

Adding a study to the page is one entry here: its module's ``Section``, where it belongs in the
order. A section whose files are not there renders nothing and is left out."""
from __future__ import annotations

from pathlib import Path

from . import base_search, classical, error_budget, headroom, observer_bound, paired_ablation, pd_baseline, perception
from . import pipeline_times, residual
from . import seeds, summary, toy as toy_page, training
from .section import SECTION_FILES, ReportContext, Section

#: the results page, top to bottom
PAGE: tuple[Section, ...] = (
    summary.SECTION,
    pd_baseline.CALIBRATION,
    pd_baseline.SENSING,
    training.SECTION,
    paired_ablation.SECTION,
    seeds.SECTION,
    base_search.SECTION,
    classical.SECTION,
    headroom.SECTION,
    observer_bound.SECTION,
    perception.SECTION,
    residual.SECTION,
    pipeline_times.SECTION,
    error_budget.SECTION,
    SECTION_FILES,
)
#: the ``--quick`` run's page (:data:`quadwind_trl.studies.toy.TOY_PREAMBLE` opens it)
TOY_PAGE: tuple[Section, ...] = (toy_page.SECTION, training.SECTION)


def render_page(preamble: str, sections: tuple[Section, ...], ctx: ReportContext) -> str:
    """``preamble`` and every section of ``sections`` that renders, in that order, one blank line
    between them."""
    parts = [preamble.rstrip(), ""] + [text for section in sections if (text := section.render(ctx)) is not None]
    return "\n".join(parts) + "\n"


def build_report(results_dir: Path, sections_dir: Path, preamble: str, policy_manifests: dict[str, dict] | None = None,
                 toy: bool = False, summary_figure: str | None = None) -> str:
    """The whole results page: the preamble, then every section of :data:`PAGE` whose inputs
    exist (the summary with ``summary_figure``, a link relative to the page, when given).
    ``toy``: the ``--quick`` run's page (:data:`TOY_PAGE`), which says so in its first line and
    shows only what it flew (no paper columns, ratios or the paper's episode counts)."""
    ctx = ReportContext(results_dir, sections_dir, policy_manifests or {}, summary_figure)
    if toy:
        return render_page(toy_page.TOY_PREAMBLE, TOY_PAGE, ctx)
    return render_page(preamble, PAGE, ctx)
