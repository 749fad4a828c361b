"""docs/results.md is what ``python recipes/report.py`` renders from the committed result files,
character for character (its text only: the figures beside it are drawn by the recipe)."""
from __future__ import annotations

import importlib.util
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _recipe():
    spec = importlib.util.spec_from_file_location("report_recipe", ROOT / "recipes" / "report.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_results_page_renders_from_the_committed_results(tmp_path):
    """The page from ``results/`` and ``docs/results/`` with the kept policies' manifests (no
    local ``runs/``) equals the committed page: a change to a section's code that moves a
    character of the page shows here, and so does a page not regenerated after a recipe ran."""
    from quadwind_trl.studies.report import build_report
    from quadwind_trl.studies.training import policy_runs

    recipe = _recipe()
    manifests, _ = policy_runs(tmp_path / "runs", ROOT / "results" / "policies")
    text = build_report(ROOT / "results", ROOT / "docs" / "results", recipe.PREAMBLE, manifests,
                        summary_figure="figures/results_summary.png")
    page = (ROOT / "docs" / "results.md").read_text()
    assert text == page, "docs/results.md differs from its rendering: run python recipes/report.py"


def _github_anchor(heading: str) -> str:
    """The anchor GitHub gives a heading (where the README's links are followed): lower case,
    punctuation dropped, each space a hyphen."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_the_readme_links_to_sections_the_results_page_has():
    """The README states each finding in a sentence or two and links to its section of
    docs/results.md for the tables: every such link names a heading the page has."""
    page = (ROOT / "docs" / "results.md").read_text()
    anchors = {_github_anchor(line.lstrip("#")) for line in page.splitlines() if line.startswith("#")}
    links = re.findall(r"\(docs/results\.md#([^)]+)\)", (ROOT / "README.md").read_text())
    assert links, "the README links to no section of docs/results.md"
    assert [link for link in links if link not in anchors] == []
