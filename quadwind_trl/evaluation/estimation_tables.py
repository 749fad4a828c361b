"""The estimation tables in markdown, beside the paper's numbers (a regime's section of
``docs/results/2_estimation.md``, made by ``recipes/evaluate_estimator.py``)."""
from __future__ import annotations

import math
import os
import re
from pathlib import Path

from ..config import TURBULENCE_LAYOUTS, TurbulenceConfig
from ..manifest import repo_relative
from .estimation import PAPER
from .estimation_run import EstimationRun


def fmt(v, digits=2):
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, tuple):
        return ", ".join(fmt(x, digits) for x in v)
    if isinstance(v, int):
        return f"{v:,}"
    return f"{v:.{digits}f}"


def table(header: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


SUMMARY_ROWS = [
    ("Per-window vector RMSE (m/s)", "per_window_vector_rmse", 2),
    ("Component-mean RMSE (m/s)", "component_mean_rmse", 2),
    ("Per-flight vector RMSE (m/s)", "per_flight_vector_rmse", 2),
    ("Direction MAE (deg)", "direction_mae_deg", 1),
    ("Correlation N", "corr_n", 4),
    ("Correlation E", "corr_e", 4),
    ("Constant-wind reference RMSE (m/s)", "reference_vector_rmse", 2),
    ("Vector skill score", "vector_skill", 3),
    ("Speed skill score", "speed_skill", 3),
    ("Speed bias, predicted - true (m/s)", "speed_bias", 3),
]


def summary_table(regime: str, columns: dict[str, dict]) -> str:
    paper = PAPER[regime]
    header = ["Metric"] + list(columns) + ["Paper"]
    rows = []
    for label, key, d in SUMMARY_ROWS:
        rows.append([label] + [fmt(c.get(key), d) for c in columns.values()] + [fmt(paper.get(key), d)])
    rows.append(["Windows"] + [fmt(c.get("n_windows")) for c in columns.values()] + ["-"])
    rows.append(["Flights"] + [fmt(c.get("n_flights")) for c in columns.values()] + ["-"])
    return table(header, rows)


def group_table(groups: dict[str, dict], label: str, paper: dict | None = None, per_flight: bool = True) -> str:
    header = [label, "windows", "flights", "per-window RMSE (m/s)", "per-flight RMSE (m/s)", "dir. MAE (deg)", "corr N", "corr E", "vector skill"]
    if paper is not None:
        header.append("paper")
    rows = []
    for name, m in groups.items():
        row = [name, fmt(m["n_windows"]), fmt(m.get("n_flights")), fmt(m["per_window_vector_rmse"]),
               fmt(m.get("per_flight_vector_rmse")), fmt(m["direction_mae_deg"], 1), fmt(m["corr_n"], 4),
               fmt(m["corr_e"], 4), fmt(m["vector_skill"], 3)]  # fmt: skip
        if paper is not None:
            row.append(paper.get(name, "-"))
        rows.append(row)
    return table(header, rows)


def floor_table(columns: dict[str, dict], estimates: dict[str, dict]) -> str:
    """The turbulence floor beside the estimator's errors, per evaluated set."""
    rows = []
    for name, fl in columns.items():
        if not fl:
            continue
        m = estimates[name]
        rows.append([name, fmt(fl.get("turbulence_rmse_instantaneous")), fmt(fl.get("turbulence_rmse_window_mean")),
                     fmt(m["per_window_vector_rmse"]), fmt(fl.get("turbulence_rmse_flight_mean")),
                     fmt(m.get("per_flight_vector_rmse"))])  # fmt: skip
    return table(["set", "true air vs label: instantaneous", "6 s window mean", "estimator per-window",
                  "flight mean", "estimator per-flight"], rows)  # fmt: skip


def sweep_table(sweep: dict[float, dict], best: float, paper: float, best_is_deployed: bool = True) -> str:
    rows = []
    for tau, m in sweep.items():
        name = "raw" if tau == 0 else f"{tau:g}"
        mark = ((" (best: deployed)" if best_is_deployed else " (best)") if tau == best else "") + (" (paper's)" if tau == paper else "")
        rows.append([name + mark, fmt(m["per_window_vector_rmse"], 3), fmt(m["direction_mae_deg"], 2),
                     fmt(m.get("per_flight_vector_rmse"), 3), fmt(m["corr_n"], 4), fmt(m["corr_e"], 4)])  # fmt: skip
    return table(["tau (s)", "per-window RMSE (m/s)", "dir. MAE (deg)", "per-flight RMSE (m/s)", "corr N", "corr E"], rows)


def estimator_description(checkpoint: str | Path, manifest: dict) -> str:
    """Which estimator the section evaluates: a trained checkpoint (its best epoch, training time)
    or a model-based one (``manifest["model_based"]``: no training; its model error)."""
    if "model_based" in manifest:
        cfg = manifest["config"]
        return (f"Model-based estimator `{manifest['model_based']}` (`--checkpoint {checkpoint}`): no training and no "
                f"checkpoint; the dataset's airframe with model error drag_scale {cfg['drag_scale']:g} (its C_dA / the true one) "
                f"and mass_scale {cfg['mass_scale']:g} (its mass / the true one)")
    return (f"Checkpoint `{repo_relative(checkpoint)}` (best epoch {manifest.get('best_epoch', '?')}, trained in "
            f"{manifest.get('metrics', {}).get('wall_time_s', '?')} s)")


def estimation_markdown(run: EstimationRun, figs: dict[str, Path], checkpoint: str | Path, manifest: dict,
                        link_base: str | Path, json_path: str | Path) -> str:
    """The regime's section: summary, turbulence floor, breakdowns, EMA sweep, unseen design,
    figure links (relative to ``link_base``); ``manifest`` is the checkpoint's, or for a
    model-based estimator ``{"model_based": class name, "config": its settings}``."""
    results, regime, deployed = run.results, run.regime, run.tau_best
    info, unseen = results["data"], run.unseen
    # only a checkpoint records its validation-best tau for the PPO recipes (--update-checkpoint)
    model_based = "model_based" in manifest
    best_label = "validation-best" if model_based else "deployed"
    t = results["test"]
    cols = {"ours: test (raw)": t["summary"]}
    if deployed in run.test_filtered:
        cols[f"ours: test, EMA tau={deployed:g} s ({best_label})"] = results["test_ema"][str(deployed)]
    if unseen is not None:
        cols["ours: unseen (raw)"] = results["unseen"]["summary"]
        if deployed in run.test_filtered:
            cols[f"ours: unseen, EMA tau={deployed:g} s ({best_label})"] = results["unseen_ema"][str(deployed)]
    paper = PAPER[regime]
    md = [f"## {regime.capitalize()} wind estimation", ""]
    md.append(
        f"{estimator_description(checkpoint, manifest)}; dataset `{info['path']}` "
        f"({info['cases']} LHS cases, seed {info['seed']}); held-out test split: {info['split_cases']['test']} wind cases, "
        f"{t['summary'].get('n_flights', 0)} flights; estimates every {results['stride']} sample(s) of the 10 Hz record past the crop. "
        f"Command: `{results['command']}` (commit `{results.get('git_commit')}`)."
    )
    md += ["", f"### Summary (paper Table {'1' if regime == 'horizontal' else '3'})", "", summary_table(regime, cols), ""]
    floors = {"test": t["turbulence_floor"]}
    ests = {"test": t["summary"]}
    if unseen is not None:
        floors["unseen"], ests["unseen"] = results["unseen"]["turbulence_floor"], results["unseen"]["summary"]
    md += [
        "### Turbulence floor (vector RMSE, m/s, of the true total wind the vehicle flies through against the mean-wind label)", "",
        "The labels exclude turbulence. A perfect sensor of the air velocity would score the floor columns against them, "
        "averaged over the same 6 s window or over the flight. The estimator can beat the window-mean column: "
        "the horizontal features' 10 s and 30 s trailing means average longer than 6 s. "
        "The flight-mean column is, approximately, the floor of the per-flight error for any estimator "
        "that perceives only the air along the flight path.", "",
        floor_table(floors, ests), "",
    ]  # fmt: skip
    traj_floor = {k: f"{v.get('turbulence_rmse_flight_mean', float('nan')):.2f}" for k, v in t["turbulence_floor_by_trajectory"].items()}
    md += ["Flight-mean turbulence floor by trajectory (m/s): " + ", ".join(f"{k} {v}" for k, v in traj_floor.items()) + ".", ""]
    if regime == "horizontal":
        traj_paper = {k: f"{v[0]:.2f} m/s, {v[1]:.1f} deg, {v[2]} flights" for k, v in paper["by_trajectory"].items()}
        md += ["### By trajectory (paper Table 2: per-flight RMSE, dir. MAE, test flights)", "", group_table(t["by_trajectory"], "trajectory", traj_paper), ""]
        speed_paper = {k: f"{v[0]:.2f} m/s, {v[1]:.1f} deg" for k, v in paper["by_speed"].items()}
        md += ["### By true wind speed (m/s; paper: RMSE 0.58 -> 1.24 m/s, dir. MAE 5.3 -> 2.1 deg)", "", group_table(t["by_speed"], "speed band", speed_paper), ""]
        md += ["### By altitude band (m)", "", group_table(t["by_altitude"], "altitude band"), ""]
    else:
        md += [f"Paper per-trajectory vector RMSE range: {paper['by_trajectory_rmse_range'][0]}-{paper['by_trajectory_rmse_range'][1]} m/s, dir. MAE 4.8-4.9 deg.", ""]
        md += ["### By trajectory", "", group_table(t["by_trajectory"], "trajectory"), ""]
        alt_paper = {"0-150": "1.29 m/s", ">450": "1.70 m/s"}
        md += ["### By altitude band (m; paper: RMSE 1.29 -> 1.70 m/s, dir. MAE 4.8-5.2 deg)", "", group_table(t["by_altitude"], "altitude band", alt_paper), ""]
        md += ["### By true wind speed (m/s)", "", group_table(t["by_speed"], "speed band"), ""]
        s = t["summary"]
        md += [
            "### Altitude-speed slope (least squares of speed on altitude, all test windows)", "",
            table(["", "ours (m/s per m)", "paper (m/s per m)"], [
                ["predicted", f"{s['altitude_speed_slope_pred']:.2e}", f"{paper['slope_pred']:.1e}"],
                ["true", f"{s['altitude_speed_slope_true']:.2e}", f"{paper['slope_true']:.1e}"],
            ]), "",
        ]  # fmt: skip
    deployment = ("The validation-best time constant is reported, not deployed: a model-based estimator has no checkpoint "
                  "to record it in, so `rl.envs.validated_tau_s` gives it the paper's tau." if model_based else
                  "The validation-best time constant is the one the PPO recipes train and fly the policy with "
                  "(`rl.envs.validated_tau_s`, recorded in the estimator's manifest).")  # fmt: skip
    md += [f"### EMA post-filter sweep on the validation flights (tau = 0: raw; paper: tau = {run.paper_tau_s:g} s best)", "",
           deployment, "", sweep_table(run.sweep, run.tau_best, run.paper_tau_s, best_is_deployed=not model_based), ""]
    if unseen is not None:
        u = results["unseen"]["summary"]
        rows_ = [["raw", fmt(u["per_window_vector_rmse"]), fmt(u["direction_mae_deg"], 1),
                  fmt(paper.get("unseen_raw_rmse")), fmt(paper.get("unseen_raw_direction_mae_deg"), 1)]]  # fmt: skip
        for tau in run.taus:
            m = results["unseen_ema"][str(tau)]
            pr = (paper.get("unseen_ema3_rmse"), paper.get("unseen_ema3_direction_mae_deg")) if tau == 3.0 else (None, None)
            rows_.append([f"EMA tau={tau:g} s", fmt(m["per_window_vector_rmse"]), fmt(m["direction_mae_deg"], 1), fmt(pr[0]), fmt(pr[1], 1)])
        md += [
            f"### Unseen LHS design (`{results['unseen_data']['path']}`, seed {results['unseen_data']['seed']}, "
            f"{results['unseen_data']['cases']} cases, all flights): raw vs filtered", "",
            table(["estimate", "per-window RMSE (m/s)", "dir. MAE (deg)", "paper RMSE", "paper dir. MAE"], rows_), "",
        ]  # fmt: skip
    rel = lambda p_: os.path.relpath(Path(p_).resolve(), Path(link_base).resolve())  # noqa: E731
    md += ["Figures:", ""] + [f"![{k}]({rel(v)})" for k, v in figs.items()] + [""]
    md.append(f"All numbers: `{json_path}`.")
    return "\n".join(md)


def replace_section(path: Path, regime: str, body: str) -> None:
    start, end = f"<!-- estimation:{regime}:start -->", f"<!-- estimation:{regime}:end -->"
    text = path.read_text() if path.exists() else "# Wind estimation results\n\nMade by `recipes/evaluate_estimator.py`; each regime's section is replaced when it is re-evaluated.\n"
    block = f"{start}\n{body.rstrip()}\n{end}"
    if start in text:
        text = re.sub(re.escape(start) + r".*?" + re.escape(end), lambda _: block, text, flags=re.S)
    else:
        text = text.rstrip() + "\n\n" + block + "\n"
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    tmp.replace(path)


def turbulence_layout(data_info: dict) -> str:
    """The turbulence layout a dataset flew, from the data block of a training or evaluation
    manifest (``estimator.training.load_estimator_data``'s info); datasets made before the layout
    was recorded flew the default, the only one the flight generator had then."""
    return data_info.get("turbulence_layout", TurbulenceConfig().layout)


def field_comparison_markdown(cells: list[tuple[str, dict, str]], paper_field: str) -> str:
    """The estimators on both turbulence fields: one row per evaluation, as
    ``(estimator label, evaluate_estimator JSON, its path)``. Each row is the evaluated field's
    held-out test split: raw per-window, per-flight and direction errors, the EMA at the tau chosen
    on that field's validation flights, and the field's own flight-mean floor (the per-flight
    error a perfect air sensor on the same flights would have); then the unseen design where
    evaluated, and per-window error by wind speed. ``paper_field``: the layout that emulates the
    paper's field, whose rows the paper's figures sit beside."""
    if paper_field not in TURBULENCE_LAYOUTS:
        raise ValueError(f"paper_field={paper_field!r}; allowed: {', '.join(map(repr, TURBULENCE_LAYOUTS))}")

    paper = PAPER["horizontal"]
    rows, unseen_rows, speed = [], [], []
    for label, r, _ in cells:
        layout = turbulence_layout(r["data"])
        s, floor, tau = r["test"]["summary"], r["test"]["turbulence_floor"], r["val_best_tau_s"]
        # tau 0 is the raw estimate (validation found no filter better); otherwise the filtered test run
        ema, ema_label = (s, "raw (best)") if tau == 0 else (r["test_ema"][str(tau)], f"{tau:g} s")
        rows.append([label, f"`{layout}`", fmt(s["per_window_vector_rmse"]), f"{fmt(ema['per_window_vector_rmse'])} ({ema_label})",
                     fmt(s["per_flight_vector_rmse"]), fmt(ema["per_flight_vector_rmse"]), fmt(floor["turbulence_rmse_flight_mean"]),
                     f"{s['per_flight_vector_rmse'] - floor['turbulence_rmse_flight_mean']:+.2f}", fmt(s["direction_mae_deg"], 1)])  # fmt: skip
        if r.get("unseen"):
            u = r["unseen"]
            unseen_rows.append([label, f"`{layout}`", fmt(u["summary"]["per_window_vector_rmse"]),
                                fmt(u["summary"]["per_flight_vector_rmse"]), fmt(u["turbulence_floor"]["turbulence_rmse_flight_mean"]),
                                fmt(u["summary"]["direction_mae_deg"], 1)])  # fmt: skip
        speed.append((label, layout, r["test"]["by_speed"]))
    rows.append([f"paper (its field, emulated by `{paper_field}`)", "-", fmt(paper["per_window_vector_rmse"]), "-",
                 fmt(paper["per_flight_vector_rmse"]), "-", "-", "-", fmt(paper["direction_mae_deg"], 1)])  # fmt: skip
    bands = list(dict.fromkeys(band for *_, groups in speed for band in groups))  # every band any row has, in order
    speed_rows = [[label, f"`{layout}`"] + [fmt(groups[b]["per_window_vector_rmse"]) if b in groups else "-" for b in bands]
                  for label, layout, groups in speed]  # fmt: skip
    speed_rows.append(["paper", "-"] + [fmt(paper["by_speed"][b][0]) if b in paper["by_speed"] else "-" for b in bands])
    md = [
        "### Trained and evaluated on each field (held-out test cases of the evaluated field)", "",
        table(["estimator", "evaluated on", "per-window raw (m/s)", "per-window EMA (validated tau)", "per-flight raw (m/s)",
               "per-flight EMA (m/s)", "field's flight-mean floor (m/s)", "per-flight raw - floor", "direction MAE raw (deg)"], rows), "",
    ]  # fmt: skip
    if unseen_rows:
        md += ["### Unseen LHS design (every flight; raw)", "",
               table(["estimator", "evaluated on", "per-window (m/s)", "per-flight (m/s)", "field's flight-mean floor (m/s)",
                      "direction MAE (deg)"], unseen_rows), ""]  # fmt: skip
    md += ["### Per-window RMSE (m/s, raw) by true wind speed (m/s), test cases", "",
           table(["estimator", "evaluated on"] + bands, speed_rows), ""]
    md += ["Commands and commits, per row:", ""]
    md += [f"- {label} on `{turbulence_layout(r['data'])}`: `{r['command']}` (commit `{r.get('git_commit')}`; all numbers `{path}`)" for label, r, path in cells]
    return "\n".join(md)
