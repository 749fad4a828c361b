"""The library's evaluation, what a user composes to judge a controller: tracking sweeps, the
paired ablation and its statistics, flight phases, exact-replay records, the estimator's
evaluation, policy validation, the airspeed demand against the envelope, the quickstart's first
flight and the figures. The project's own studies, and the results page, are in
:mod:`quadwind_trl.studies` (docs/architecture.md)."""
