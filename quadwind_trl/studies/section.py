"""The interface between the results page and the studies: a :class:`Section` of
``docs/results.md`` and the :class:`ReportContext` every section renders from.

A study renders its own section. Its module defines the text (a function of the study's result
files) and one ``Section`` value naming the files it reads and a ``render(ctx)`` that returns the
section's markdown, or ``None`` when its files are not there (the page then leaves it out). The
page (:mod:`quadwind_trl.studies.report`) only orders and joins the registered sections, so adding
a study is its module and one entry in :data:`quadwind_trl.studies.report.PAGE`; the cells that
more than one section prints are in :mod:`quadwind_trl.studies.tables`::

    SECTION = Section.of_results("my_study", "What my study measures", "my_study.json", my_study_section)

A section that reads more than its own result files gives ``Section`` a ``render(ctx)`` of its own.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, Callable, Mapping

from ..regimes import SWEEPS, VALIDATION_SWEEPS


def read_ablations(folder: Path) -> dict[str, dict]:
    """The ablation results files in ``folder``, by sweep (those that exist)."""
    return {name: json.loads((folder / f"ablation_{name}.json").read_text())
            for name in SWEEPS if (folder / f"ablation_{name}.json").exists()}


def read_seed_ablations(results_dir: Path) -> dict[str, dict[str, dict]]:
    """Every training seed's ablation files (``RESULTS/seeds/seed<k>/``), by seed name (``"0"``, ...)."""
    seeds = {path.name.removeprefix("seed"): read_ablations(path) for path in sorted((results_dir / "seeds").glob("seed*"))}
    return {seed: r for seed, r in seeds.items() if r}


def read_searches(folder: Path) -> dict[str, dict]:
    """The base-controller validation searches in ``folder``, by regime (those that exist)."""
    return {regime: json.loads((folder / f"base_search_{regime}.json").read_text())
            for regime in VALIDATION_SWEEPS if (folder / f"base_search_{regime}.json").exists()}


@dataclass(frozen=True)
class ReportContext:
    """What every section renders from: the results folder (``results/``), the folder of section
    files the estimator recipes write (``docs/results/``), the PPO runs' manifests by run name,
    and the at-a-glance figure's link relative to the page (``None``: no figure). The result files
    more than one section reads are parsed once, on first use."""

    results: Path
    sections: Path
    manifests: Mapping[str, dict] = field(default_factory=dict)
    summary_figure: str | None = None

    def json(self, name: str) -> dict | None:
        """``RESULTS/name`` parsed, ``None`` when it does not exist."""
        path = self.results / name
        return json.loads(path.read_text()) if path.exists() else None

    def jsons(self, pattern: str) -> dict[str, dict]:
        """Every results file matching the glob ``pattern`` (under the results folder), parsed, by
        its path under the folder without ``.json`` (a top-level file: its stem), in name order."""
        return {path.relative_to(self.results).with_suffix("").as_posix(): json.loads(path.read_text())
                for path in sorted(self.results.glob(pattern))}

    @cached_property
    def ablations(self) -> dict[str, dict]:
        """The shipped policies' paired ablation (``results/ablation_<sweep>.json``), by sweep."""
        return read_ablations(self.results)

    @cached_property
    def seeds(self) -> dict[str, dict[str, dict]]:
        """Every training seed's paired ablation (``results/seeds/seed<k>/``), by seed name."""
        return read_seed_ablations(self.results)

    @cached_property
    def classical(self) -> dict[str, dict]:
        """The classical controllers on the test sweeps (``results/classical/ablation_<sweep>.json``)."""
        return read_ablations(self.results / "classical")

    @cached_property
    def searches(self) -> dict[str, dict]:
        """The base-controller validation searches (``results/base_search_<regime>.json``)."""
        return read_searches(self.results)


@dataclass(frozen=True)
class Section:
    """One section of the results page.

    ``name``: the registry's key; ``title``: the heading the section opens with (``## title``, or
    the start of it where the heading names what a file holds; empty where the files it appends
    bring their own headings); ``reads``: the committed files it renders from, as globs relative to
    the repository (``results/...``); ``render``: the markdown, or ``None`` when those files are
    not there."""

    name: str
    title: str
    reads: tuple[str, ...]
    render: Callable[[ReportContext], str | None]

    @classmethod
    def of_results(cls, name: str, title: str, pattern: str, section: Callable[[Any], str]) -> "Section":
        """The section of a study whose text is one function of its result files: ``section`` of
        ``RESULTS/pattern`` parsed, or, where ``pattern`` is a glob, of every matching file parsed
        (by file stem, :meth:`ReportContext.jsons`); left out when there is none."""
        is_glob = any(c in pattern for c in "*?[")

        def render(ctx: ReportContext) -> str | None:
            if is_glob:
                results = ctx.jsons(pattern)
                return section(results) if results else None
            result = ctx.json(pattern)
            return None if result is None else section(result)

        return cls(name, title, (f"results/{pattern}",), render)


def _section_files(ctx: ReportContext) -> str | None:
    """The section files in ``ctx.sections`` (``docs/results/*.md``), in name order."""
    files = sorted(ctx.sections.glob("*.md"))
    return "\n".join(part for path in files for part in (path.read_text().rstrip(), "")) if files else None


#: the sections the estimator recipes write as markdown files (``recipes/evaluate_estimator.py``,
#: ``recipes/estimator_experiments.py``, ...), appended as they are
SECTION_FILES = Section("section_files", "", ("docs/results/*.md",), _section_files)
