"""The project's studies: the questions this repository asks of the method (the envelope check,
where the tails come from, what the estimate is worth, the residual on a classical base, the
error budget, the base-controller search, the estimator experiments, the paper's tables), one
module per study with its recipe in ``recipes/``, and the results page assembled from the
sections they render (:mod:`.section`, :mod:`.report`). Studies build on
:mod:`quadwind_trl.evaluation`; nothing in the library imports them (docs/architecture.md)."""
