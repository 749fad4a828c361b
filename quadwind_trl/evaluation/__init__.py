"""The paper's analysis: estimator evaluation, tracking sweeps, the paired ablation and its
statistics, the error budget, replay records, figures and the report (docs/architecture.md)."""
