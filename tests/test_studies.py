"""The studies' home: the results page is the registered sections in order, each rendering its
own files, and the names that moved out of the library's evaluation still import from their old
paths for one release, with a warning that names the new home."""
from __future__ import annotations

import importlib
import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

# the public names of the old results renderer, quadwind_trl.evaluation.report, and where each lives now:
# written out here rather than read from the re-export's own table, so the old API is checked against an
# independent list (a name dropped from that table would otherwise drop out of this test too)
REPORT_NAMES = {
    "report": ("build_report",),
    "section": ("read_ablations", "read_searches", "read_seed_ablations"),
    "tables": ("headroom_pct", "wall_time", "SWEEP_TITLES"),
    "summary": ("SUMMARY_CLAIMS", "CLASSICAL_PENDING", "best_classical", "summary_rows", "summary_section", "page_summary_rows"),
    "pd_baseline": ("pd_calibration_section", "sensing_presets_section"),
    "training": ("policy_runs", "training_section"),
    "paired_ablation": ("perception_tables", "ablation_section"),
    "seeds": ("SEED_SWEEPS", "SEED_MEASURES", "seeds_section"),
    "base_search": ("FAMILY_LABEL", "FIELD_LABEL", "POLICY_KINDS", "classical_section"),
    "classical": ("classical_sweeps_section",),
    "perception": ("PERCEPTION_VALUES", "PERCEPTION_SHARES", "perception_sweep_tables", "FEEDFORWARD_VALUES",
                   "feedforward_value_table", "perception_phase_table", "perception_variants_table", "perception_section"),
    "residual": ("RESIDUAL_VALUES", "RESIDUAL_GOAL", "residual_section"),
    "pipeline_times": ("pipeline_section",),
    "error_budget": ("SENSING_LABEL", "error_budget_section"),
    "toy": ("TOY_PREAMBLE", "toy_tracking_section"),
}
# (old module, name, new module): a name of each module that moved whole, and of those split in two
MOVED = [("quadwind_trl.evaluation.report", name, f"quadwind_trl.studies.{home}")
         for home, names in REPORT_NAMES.items() for name in names] + [
    ("quadwind_trl.evaluation.perception", "analyse_sweep", "quadwind_trl.studies.perception"),
    ("quadwind_trl.evaluation.perception", "across_seeds", "quadwind_trl.studies.perception"),
    ("quadwind_trl.evaluation.residual", "analyse_residual", "quadwind_trl.studies.residual"),
    ("quadwind_trl.evaluation.error_budget", "error_budget", "quadwind_trl.studies.error_budget"),
    ("quadwind_trl.evaluation.diagnosis", "step_diagnostics", "quadwind_trl.studies.diagnosis"),
    ("quadwind_trl.evaluation.base_search", "select_candidate", "quadwind_trl.studies.base_search"),
    ("quadwind_trl.evaluation.estimation_experiments", "experiments_markdown", "quadwind_trl.studies.estimation_experiments"),
    ("quadwind_trl.evaluation.paper", "TRACKING_STATS", "quadwind_trl.studies.paper"),
    ("quadwind_trl.evaluation.envelope", "sweep_cells", "quadwind_trl.studies.envelope"),
    ("quadwind_trl.evaluation.envelope", "hold_check", "quadwind_trl.studies.envelope"),
    ("quadwind_trl.evaluation.figures", "perception_value", "quadwind_trl.studies.perception"),
    ("quadwind_trl.evaluation.figures", "diagnosis_groups", "quadwind_trl.studies.diagnosis"),
    ("quadwind_trl.evaluation.figures", "results_summary", "quadwind_trl.studies.summary"),
]


@pytest.mark.parametrize("old, name, new", MOVED, ids=[f"{o.rsplit('.', 1)[1]}.{n}" for o, n, _ in MOVED])
def test_a_moved_name_imports_from_its_old_path_with_a_warning(old, name, new):
    with pytest.warns(DeprecationWarning, match=rf"{old}\.{name} has moved to {new}\.{name}"):
        value = getattr(importlib.import_module(old), name)
    assert value is getattr(importlib.import_module(new), name)


def test_the_old_from_import_form_warns_too_and_unknown_names_still_fail():
    with pytest.warns(DeprecationWarning, match="quadwind_trl.studies.report.build_report"):
        from quadwind_trl.evaluation.report import build_report
    from quadwind_trl.studies.report import build_report as new

    assert build_report is new
    old = importlib.import_module("quadwind_trl.evaluation.perception")
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        old.not_a_name
    with pytest.raises(AttributeError, match="no attribute 'pattern_speed_of'"):
        importlib.import_module("quadwind_trl.evaluation.envelope").pattern_speed_of


def test_what_stayed_in_the_library_imports_without_a_warning():
    """The airspeed demand, the figures and the statistics a user composes are the library's own."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        from quadwind_trl.evaluation.envelope import airspeed_demand  # noqa: F401
        from quadwind_trl.evaluation.figures import ablation_figures, learning_curves  # noqa: F401
        from quadwind_trl.evaluation.statistics import across_seeds, t_interval  # noqa: F401


def _context(results: Path, sections: Path, manifests=None):
    from quadwind_trl.studies.section import ReportContext

    return ReportContext(results, sections, manifests or {}, "figures/results_summary.png")


def test_every_section_reads_committed_files_and_opens_with_its_title(tmp_path):
    """Each registered section names files the repository holds and renders from them, under the
    heading its ``title`` gives (the section files bring their own)."""
    from quadwind_trl.studies.report import PAGE
    from quadwind_trl.studies.training import policy_runs

    manifests, _ = policy_runs(tmp_path / "runs", ROOT / "results" / "policies")
    ctx = _context(ROOT / "results", ROOT / "docs" / "results", manifests)
    assert len({section.name for section in PAGE}) == len(PAGE)
    for section in PAGE:
        assert any(any(ROOT.glob(pattern)) for pattern in section.reads), (section.name, section.reads)
        text = section.render(ctx)
        assert text is not None, section.name
        first = text.splitlines()[0]
        assert first.startswith("#"), (section.name, first)
        assert first.lstrip("#").strip().startswith(section.title), (section.name, first)


def test_a_section_whose_files_are_missing_is_left_out(tmp_path):
    from quadwind_trl.studies.report import PAGE, build_report, render_page
    from quadwind_trl.studies.section import Section

    empty = _context(tmp_path, tmp_path)
    assert [section.name for section in PAGE if section.render(empty) is not None] == []
    assert build_report(tmp_path, tmp_path, "# Results\n") == "# Results\n\n"
    # a study's section sits where the page's order puts it
    mine = Section("mine", "Mine", ("results/mine.json",), lambda ctx: "## Mine\n\ntext\n")
    assert render_page("# Results", (PAGE[0], mine, PAGE[-1]), empty) == "# Results\n\n## Mine\n\ntext\n\n"


@pytest.mark.parametrize("residual_on, components", [("wrench", ("T", "x", "y", "z")),
                                                     ("acceleration", ("fwd", "left", "U"))])
def test_the_tail_diagnosis_names_channels_and_action_components_in_the_policys_layout(residual_on, components):
    import torch
    from tensordict import TensorDict

    from quadwind_trl.keys import observation_channels
    from quadwind_trl.studies.diagnosis import SCALAR_INDICATORS, group_summary

    channels = observation_channels(residual_on)
    episodes = 3
    scalars = {k: torch.zeros(episodes) for k in SCALAR_INDICATORS}
    out_of_range = torch.zeros(episodes, len(channels))
    out_of_range[:, -1] = 0.5  # only the last channel, the residual's own last component, leaves its range
    action = torch.arange(1.0, len(components) + 1).expand(episodes, -1)
    aware = TensorDict({**scalars, "obs_out_of_range_by_channel": out_of_range, "action_mean_abs": action}, [episodes])
    summary = group_summary({"pd": TensorDict(scalars, [episodes]), "aware": aware}, range(episodes), residual_on)
    assert summary["aware"]["channels_out_of_range"] == {channels[-1]: 0.5}
    assert summary["aware"]["action_mean_abs"] == dict(zip(components, range(1, len(components) + 1)))
