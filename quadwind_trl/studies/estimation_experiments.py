"""The estimator experiments as markdown: each training run's validation
figures beside the shipped recipe's, what it changed, and the test figures of the runs chosen
on validation only (``recipes/estimator_experiments.py`` writes the section).

A training manifest (``recipes/train_estimator.py``'s JSON beside a checkpoint) holds the run's
configuration and its best validation epoch (``val_metrics``: every validation flight, windows
every 4.8 s); what a run changed is the difference of its configuration from the reference's,
so no row is labelled by hand.
"""
from __future__ import annotations

from ..estimator.features import DEFAULT_TRAILING_WINDOWS
from ..estimator.training import TrainConfig
from ..evaluation.estimation import FLIGHT_AGGREGATES
from ..evaluation.estimation_tables import fmt, table

#: configuration entries that do not change what is learned
IGNORED = ("compile", "log_every_steps", "eval_batch_size", "test_stride")


def flatten(config: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in config.items():
        if isinstance(v, dict):
            out.update(flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = tuple(v) if isinstance(v, list) else v
    return out


def run_config(manifest: dict) -> dict:
    """A training manifest's configuration with ``trailing_windows`` set to the trailing means its
    features really had. The manifest's dataset entry is the record where present: a vertical
    run made before that schema could have trailing means has the horizontal default in its
    configuration. Manifests older than the setting used their regime's default."""
    config = dict(manifest["config"])
    if "trailing_windows" in manifest.get("dataset", {}):
        config["trailing_windows"] = list(manifest["dataset"]["trailing_windows"] or ())
    elif "trailing_windows" not in config:
        config["trailing_windows"] = list(DEFAULT_TRAILING_WINDOWS[config["regime"]])
    return config


def config_change(config: dict, reference: dict) -> str:
    """``key: reference -> run`` for each setting that differs (defaults of settings the
    reference predates are the reference's values: a run that left them alone changed nothing)."""
    run, ref = flatten(config), flatten(reference)
    defaults = flatten(TrainConfig(regime=reference["regime"]).to_dict())
    changes = []
    for key, value in run.items():
        before = ref.get(key, defaults.get(key))
        if key not in IGNORED and before != value:
            changes.append(f"{key} {_show(before)} -> {_show(value)}")
    return "; ".join(changes) or "none (the shipped recipe)"


def _show(v) -> str:
    return ("-".join(map(str, v)) or "none") if isinstance(v, tuple) else str(v)


def experiments_markdown(reference: dict, runs: list[tuple[str, dict]], evaluations: list[tuple[str, dict, str]],
                         floors: dict[str, dict[int, float]] | None = None, dt_s: float = 0.1) -> str:
    """``reference``: the shipped checkpoint's manifest; ``runs``: ``(path, manifest)`` of each
    experiment's checkpoint; ``evaluations``: ``(label, evaluate_estimator JSON, path)`` of the
    shipped estimator and of the runs chosen on validation, for the test table and the per-flight
    aggregation table; ``floors``: rows of the validation windows' trailing-mean floors, each by
    length in samples (``evaluation.estimation.trailing_mean_floor``; ``dt_s`` per sample)."""
    ref_val, regime = reference["val_metrics"], reference["config"]["regime"]
    rows = []
    runs = [(f"quadwind_trl/checkpoints/estimator_{regime}.pt (shipped)", reference)] + list(runs)
    for path, m in runs:
        v = m["val_metrics"]
        wall = (m.get("history_tail") or [{}])[-1].get("wall_time_s")
        rows.append([f"`{path}`", config_change(run_config(m), run_config(reference)), fmt(m.get("parameters")),
                     f"{m['best_epoch']} / {m['epochs_run']}", fmt(v["per_window_vector_rmse"], 3),
                     f"{v['per_window_vector_rmse'] - ref_val['per_window_vector_rmse']:+.3f}",
                     fmt(v["per_flight_vector_rmse"], 3), fmt(v["direction_mae_deg"], 2), fmt(v.get("vector_skill"), 3),
                     fmt(wall / 60 if wall else None, 0)])  # fmt: skip
    stride_s = (reference["config"].get("val_stride") or 1) * dt_s
    md = [
        f"### {regime.capitalize()} validation (the selection): best epoch of each run, every validation flight, "
        f"windows every {stride_s:g} s", "",
        table(["checkpoint", "changed", "parameters", "best / run epochs", "per-window (m/s)", "vs shipped",
               "per-flight (m/s)", "direction MAE (deg)", "vector skill", "training (min)"], rows), "",
    ]  # fmt: skip
    if floors:
        md += [
            "The air itself, averaged (a yardstick: what a perfect air sensor would score, averaged uniformly, on the same "
            "validation windows; a network that weighs several means can do a little better): the true total "
            "wind at the vehicle averaged over the last T seconds before each window's end (expanding while there is less), "
            "against the mean-wind label, per-window RMSE (m/s):", "",
            table(["averaged from", *(f"last {w * dt_s:g} s" for w in next(iter(floors.values())))],
                  [[name] + [fmt(v, 3) for v in row.values()] for name, row in floors.items()]), "",
        ]  # fmt: skip
    md += ["Training commands and commits:", ""]
    md += [f"- `{path}`: `{m.get('command')}` (commit `{m.get('git_commit')}`)" for path, m in runs]
    md.append("")
    if not evaluations:
        return "\n".join(md)
    test_rows, agg_rows = [], []
    for label, r, _ in evaluations:
        s, floor, tau = r["test"]["summary"], r["test"]["turbulence_floor"], r["val_best_tau_s"]
        ema = s if tau == 0 else r["test_ema"][str(tau)]
        val_agg = r.get("val_flight_aggregation", {})
        test_rows.append([label, fmt(s["per_window_vector_rmse"], 3), f"{fmt(ema['per_window_vector_rmse'], 3)} ({tau:g} s)",
                          fmt(s["per_flight_vector_rmse"], 3), fmt(floor["turbulence_rmse_flight_mean"], 3),
                          f"{s['per_flight_vector_rmse'] - floor['turbulence_rmse_flight_mean']:+.3f}",
                          fmt(s["direction_mae_deg"], 1), fmt(s["vector_skill"], 3)])  # fmt: skip
        for t, rules in val_agg.items():
            best = min(rules, key=rules.get)
            test = r.get("test_flight_aggregation", {}).get(t, {})
            agg_rows.append([label, "raw" if float(t) == 0 else f"EMA {float(t):g} s"]
                            + [fmt(rules[k], 3) + (" **best**" if k == best else "") for k in FLIGHT_AGGREGATES]
                            + [f"{best}: {fmt(test.get(best), 3)} (mean: {fmt(test.get('mean'), 3)})"])  # fmt: skip
    md += [
        f"### {regime.capitalize()} test cases (flown once, for the shipped estimator and the runs chosen on validation)", "",
        table(["estimator", "per-window raw (m/s)", "per-window EMA (validated tau)", "per-flight raw (m/s)",
               "flight-mean floor (m/s)", "per-flight - floor", "direction MAE (deg)", "vector skill"], test_rows), "",
    ]  # fmt: skip
    if agg_rows:
        md += [
            f"### {regime.capitalize()} per-flight aggregation: how a flight's estimates become one (validation per-flight RMSE, m/s; "
            "the rule chosen there, on test)", "",
            table(["estimator", "estimates"] + list(FLIGHT_AGGREGATES) + ["test, chosen rule"], agg_rows), "",
        ]  # fmt: skip
    md += ["Evaluation commands and commits:", ""]
    md += [f"- {label}: `{r['command']}` (commit `{r.get('git_commit')}`; `{path}`)" for label, r, path in evaluations]
    return "\n".join(md)
