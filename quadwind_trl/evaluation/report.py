"""Moved: the results page is rendered by :mod:`quadwind_trl.studies.report` from the sections the
studies define (:mod:`quadwind_trl.studies.section`). The names this module had warn here, and go
in the next release."""
from ._moved import moved

_STUDIES = "quadwind_trl.studies"
__getattr__ = moved(__name__, {name: f"{_STUDIES}.{home}" for home, names in {
    "report": ("build_report",),
    "section": ("read_ablations", "read_searches", "read_seed_ablations"),
    "tables": ("headroom_pct", "wall_time", "SWEEP_TITLES"),
    "summary": ("SUMMARY_CLAIMS", "CLASSICAL_PENDING", "best_classical", "summary_rows", "summary_section",
                "page_summary_rows"),
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
}.items() for name in names})
