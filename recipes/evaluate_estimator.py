"""Evaluate a trained wind estimator: the paper's estimation tables and figures.

    python recipes/evaluate_estimator.py --regime horizontal --data data/flights_horizontal \
        [--checkpoint quadwind_trl/checkpoints/estimator_horizontal.pt] [--unseen-data DIR]
    python recipes/evaluate_estimator.py --regime vertical --data data/flights_vertical \
        --unseen-data data/flights_vertical_unseen --update-checkpoint

On the held-out test wind cases of --data (the training split, by wind case) and, with
--unseen-data, on every flight of an independently generated LHS design (a disjoint --seed):

* estimates at every 10 Hz sample past each flight's crop (--stride 1);
* metrics (summary; by true wind speed, altitude band, trajectory); vertical: skill scores and the
  altitude-speed slope;
* the EMA post-filter sweep over tau on the validation flights (``ema_scan`` over each flight's
  sequence of estimates), then raw vs filtered on test (and unseen);
* markdown tables beside the paper's numbers in --md (this regime's section is replaced, the other
  regime's kept), figures in --fig-dir, all numbers in --json.

--update-checkpoint writes the validation-selected tau and the evaluation metrics into the
checkpoint (and its manifest).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
from quadwind_trl.manifest import command_line, repo_relative
import sys
import time
from pathlib import Path

import torch

from quadwind_trl.evaluation.estimation import (
    PAPER,
    TAU_SWEEP_S,
    EMAConfig,
    FlightSequences,
    best_tau,
    ema_sweep,
    evaluate_sequences,
    predict_flights,
)
from quadwind_trl.envs.trajectories import TRAJECTORIES
from quadwind_trl.estimator import EstimatorBundle
from quadwind_trl.manifest import CHECKPOINT_DIR
from quadwind_trl.estimator.training import EstimatorData, load_estimator_data, split_flights


def sequences(bundle: EstimatorBundle, ed: EstimatorData, flights: torch.Tensor, stride: int, batch: int, desc: str) -> FlightSequences:
    wd, rec = ed.windows, ed.data["record"]
    pos = torch.as_tensor(rec["pos"])
    wind = torch.as_tensor(rec["wind"])
    t0 = time.perf_counter()
    seq = predict_flights(
        bundle.predict, wd.features, wd.labels, pos[..., 2], flights, wd.crop, wd.length,
        ed.data["traj_id"], ed.data["case_id"], wind=torch.stack((wind[..., 1], wind[..., 0]), -1),
        window=wd.window, stride=stride, batch_size=batch, record_dt_s=ed.manifest["record_dt_s"], progress=True,
    )  # fmt: skip
    n = int(seq.mask.sum())
    dt = time.perf_counter() - t0
    print(f"{desc}: {flights.numel()} flights, {n:,} windows estimated in {dt:.1f} s ({n / max(dt, 1e-9):.0f} windows/s)", flush=True)
    return seq


def ema_cfg(tau: float, dt: float) -> EMAConfig:
    return EMAConfig(tau_s=tau, dt_s=dt)


# ---------------------------------------------------------------------------------------------
# tables
# ---------------------------------------------------------------------------------------------


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


def sweep_table(sweep: dict[float, dict], best: float, deployed: float) -> str:
    rows = []
    for tau, m in sweep.items():
        name = "raw" if tau == 0 else f"{tau:g}"
        mark = (" (best)" if tau == best else "") + (" (deployed)" if tau == deployed else "")
        rows.append([name + mark, fmt(m["per_window_vector_rmse"], 3), fmt(m["direction_mae_deg"], 2),
                     fmt(m.get("per_flight_vector_rmse"), 3), fmt(m["corr_n"], 4), fmt(m["corr_e"], 4)])  # fmt: skip
    return table(["tau (s)", "per-window RMSE (m/s)", "dir. MAE (deg)", "per-flight RMSE (m/s)", "corr N", "corr E"], rows)


# ---------------------------------------------------------------------------------------------
# figures
# ---------------------------------------------------------------------------------------------


def error_bars_figure(groups: dict[str, dict], xlabel: str, title: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(groups)
    rmse = [groups[k]["per_window_vector_rmse"] for k in names]
    mae = [groups[k]["direction_mae_deg"] for k in names]
    corr = [0.5 * (groups[k]["corr_n"] + groups[k]["corr_e"]) for k in names]
    fig, ax = plt.subplots(figsize=(6.5, 4))
    bars = ax.bar(names, rmse, color="tab:blue", alpha=0.75, label="per-window vector RMSE")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("per-window vector RMSE (m/s)", color="tab:blue")
    for b, c, k in zip(bars, corr, names):
        ax.annotate(f"r={c:.3f}\nn={groups[k]['n_windows']:,}", (b.get_x() + b.get_width() / 2, b.get_height() / 2),
                    ha="center", va="center", fontsize=7, color="white")  # fmt: skip
    ax.set_ylim(0, max(rmse) * 1.3 if rmse else 1)
    ax2 = ax.twinx()
    ax2.plot(names, mae, "o-", color="tab:red", label="direction MAE")
    ax2.set_ylabel("direction MAE (deg)", color="tab:red")
    ax2.set_ylim(0, max(mae) * 1.3 if mae else 1)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def timeseries_figure(seq: FlightSequences, rows: list[int], names: list[str], filtered: torch.Tensor | None, tau: float, title: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(rows), 2, figsize=(11, 2.1 * len(rows) + 0.6), squeeze=False, sharex="row")
    for r, (i, name) in enumerate(zip(rows, names)):
        m = seq.mask[i]
        t = seq.end[i][m].float() * 0.1
        err = (seq.pred[i][m] - seq.true[i][m]).mean(0).norm().item()
        for c, comp in enumerate(("north", "east")):
            ax = axes[r][c]
            ax.plot(t, seq.wind[i][m][:, c], color="0.75", lw=0.6, label="total wind (turbulent)")
            ax.plot(t, seq.true[i][m][:, c], "k--", lw=1.2, label="true mean wind")
            ax.plot(t, seq.pred[i][m][:, c], color="tab:blue", lw=0.9, label="estimate (raw)")
            if filtered is not None:
                ax.plot(t, filtered[i][m][:, c], color="tab:orange", lw=1.1, ls=":", label=f"EMA tau={tau:g} s")
            ax.set_ylabel(f"{comp} (m/s)")
            ax.set_title(f"{name}: {comp}; per-flight error {err:.2f} m/s", fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    axes[0][0].legend(fontsize=7, loc="best")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def example_case(seq: FlightSequences, target_speed: float | None) -> int:
    """The case whose mean true speed is closest to ``target_speed`` (None: the median case)."""
    w = seq.windows()
    cases = torch.unique(w["case_id"])
    speeds = torch.stack([w["true"][w["case_id"] == c].norm(dim=-1).mean() for c in cases])
    if target_speed is None:
        return int(cases[torch.argsort(speeds)[len(cases) // 2]])
    return int(cases[torch.argmin((speeds - target_speed).abs())])


def case_rows(seq: FlightSequences, case: int) -> tuple[list[int], list[str]]:
    rows = torch.nonzero(seq.case_id == case).flatten().tolist()
    rows.sort(key=lambda i: int(seq.traj_id[i]))
    return rows, [TRAJECTORIES[int(seq.traj_id[i])] for i in rows]


# ---------------------------------------------------------------------------------------------


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


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--regime", required=True, choices=["horizontal", "vertical"])
    p.add_argument("--checkpoint", default=None, help="default: the shipped quadwind_trl/checkpoints/estimator_<regime>.pt")
    p.add_argument("--data", required=True, help="the training dataset (its held-out test cases are evaluated)")
    p.add_argument("--unseen-data", default=None, help="an independently generated dataset (disjoint LHS seed): all its flights")
    p.add_argument("--stride", type=int, default=1, help="samples between evaluated windows (1: every 10 Hz sample)")
    p.add_argument("--taus", type=float, nargs="+", default=list(TAU_SWEEP_S), help="EMA time constants to sweep (0 = raw)")
    p.add_argument("--batch", type=int, default=1024)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--quick", action="store_true", help="the dataset is a --quick one (split in thirds if needed)")
    p.add_argument("--md", default="docs/results/2_estimation.md",
                   help="section file (one section per regime) that recipes/report.py merges into docs/results.md")
    p.add_argument("--link-base", default="docs", help="figure links are relative to this folder (where docs/results.md is)")
    p.add_argument("--fig-dir", default="docs/figures")
    p.add_argument("--json", default=None, help="default: results/estimation_<regime>.json")
    p.add_argument("--update-checkpoint", action="store_true", help="store the val-selected tau and these metrics in the checkpoint")
    args = p.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    regime = args.regime
    ckpt = Path(args.checkpoint) if args.checkpoint else CHECKPOINT_DIR / f"estimator_{regime}.pt"
    fig_dir = Path(args.fig_dir)
    fig_dir.mkdir(parents=True, exist_ok=True)
    json_path = Path(args.json) if args.json else Path("results") / f"estimation_{regime}.json"
    t_start = time.perf_counter()

    try:
        ed = load_estimator_data(args.data, regime, quick=args.quick)
    except (FileNotFoundError, ValueError) as err:
        p.error(str(err))
    try:
        bundle = EstimatorBundle.load(ckpt, expect_channels=ed.windows.channels)
    except (FileNotFoundError, ValueError) as err:
        p.error(str(err))
    trained_on = bundle.manifest.get("dataset", {}).get("manifest_sha256")
    if trained_on and trained_on != ed.info["manifest_sha256"]:
        print(f"WARNING: {ckpt} was trained on another dataset ({bundle.manifest['dataset'].get('path')}); its test split may overlap training", flush=True)
    names = list(TRAJECTORIES)
    deployed = bundle.ema_tau_s
    results: dict = {"regime": regime, "checkpoint": repo_relative(ckpt), "data": ed.info, "stride": args.stride,
                     "command": command_line(sys.argv), "deployed_tau_s": deployed}  # fmt: skip

    # EMA sweep on validation flights
    val = sequences(bundle, ed, split_flights(ed.windows, "val"), args.stride, args.batch, "validation")
    sweep = ema_sweep(val, args.taus)
    tau_best = best_tau(sweep)
    results["val_ema_sweep"] = {str(k): v for k, v in sweep.items()}
    results["val_best_tau_s"] = tau_best
    del val

    # held-out test cases
    test = sequences(bundle, ed, split_flights(ed.windows, "test"), args.stride, args.batch, "test")
    results["test"] = evaluate_sequences(test, names)
    taus = sorted({deployed, tau_best} - {0.0})
    test_f = {tau: test.filtered(ema_cfg(tau, test.dt_s)) for tau in taus}
    results["test_ema"] = {str(tau): evaluate_sequences(test, names, pred=f)["summary"] for tau, f in test_f.items()}

    unseen = None
    if args.unseen_data:
        try:
            ue = load_estimator_data(args.unseen_data, regime, quick=args.quick)
        except (FileNotFoundError, ValueError) as err:
            p.error(f"--unseen-data: {err}")
        if ue.info["seed"] == ed.info["seed"]:
            print(f"WARNING: --unseen-data has the same LHS seed ({ue.info['seed']}) as --data: not an independent design", flush=True)
        flights = torch.unique(torch.cat([ue.windows.tables[s][:, 0] for s in ("train", "val", "test")]))
        unseen = sequences(bundle, ue, flights, args.stride, args.batch, "unseen")
        results["unseen"] = evaluate_sequences(unseen, names)
        results["unseen_data"] = ue.info
        unseen_f = {tau: unseen.filtered(ema_cfg(tau, unseen.dt_s)) for tau in taus}
        results["unseen_ema"] = {str(tau): evaluate_sequences(unseen, names, pred=f)["summary"] for tau, f in unseen_f.items()}

    # ---- figures ----
    figs = {}
    tag = f"estimation_{regime}"
    figs["speed"] = fig_dir / f"{tag}_error_vs_speed.png"
    error_bars_figure(results["test"]["by_speed"], "true wind speed (m/s)", f"{regime} estimator, held-out test cases: error vs wind speed", figs["speed"])
    if regime == "vertical":
        figs["altitude"] = fig_dir / f"{tag}_error_vs_altitude.png"
        error_bars_figure(results["test"]["by_altitude"], "altitude band (m)", "vertical estimator, held-out test cases: error vs altitude", figs["altitude"])
    src, src_name = (unseen, "unseen") if (regime == "vertical" and unseen is not None) else (test, "held-out test")
    src_f = (unseen_f if src is unseen else test_f).get(deployed)
    case = example_case(src, 3.8 if regime == "horizontal" else None)
    rows, labels = case_rows(src, case)
    figs["timeseries"] = fig_dir / f"{tag}_timeseries.png"
    timeseries_figure(
        src, rows, labels, src_f if regime == "vertical" else None, deployed,
        f"{regime} estimation, {src_name} wind case {case}", figs["timeseries"],
    )  # fmt: skip
    results["figures"] = {k: str(v) for k, v in figs.items()}
    results["example_case"] = case

    # ---- markdown ----
    t = results["test"]
    cols = {"ours: test (raw)": t["summary"]}
    if deployed in test_f:
        cols[f"ours: test, EMA tau={deployed:g} s"] = results["test_ema"][str(deployed)]
    if unseen is not None:
        cols["ours: unseen (raw)"] = results["unseen"]["summary"]
        if deployed in test_f:
            cols[f"ours: unseen, EMA tau={deployed:g} s"] = results["unseen_ema"][str(deployed)]
    paper = PAPER[regime]
    rel = lambda p_: os.path.relpath(Path(p_).resolve(), Path(args.link_base).resolve())  # noqa: E731
    md = [f"## {regime.capitalize()} wind estimation", ""]
    md.append(
        f"Checkpoint `{ckpt}` (best epoch {bundle.manifest.get('best_epoch', '?')}, trained in "
        f"{bundle.manifest.get('metrics', {}).get('wall_time_s', '?')} s); dataset `{ed.info['path']}` "
        f"({ed.info['cases']} LHS cases, seed {ed.info['seed']}); held-out test split: {ed.info['split_cases']['test']} wind cases, "
        f"{t['summary'].get('n_flights', 0)} flights; estimates every {args.stride} sample(s) of the 10 Hz record past the crop. "
        f"Command: `{results['command']}`."
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
    md += ["### EMA post-filter sweep on the validation flights (tau = 0: raw; paper: tau = 3 s best)", "", sweep_table(sweep, tau_best, deployed), ""]
    if unseen is not None:
        u = results["unseen"]["summary"]
        rows_ = [["raw", fmt(u["per_window_vector_rmse"]), fmt(u["direction_mae_deg"], 1),
                  fmt(paper.get("unseen_raw_rmse")), fmt(paper.get("unseen_raw_direction_mae_deg"), 1)]]  # fmt: skip
        for tau in taus:
            m = results["unseen_ema"][str(tau)]
            pr = (paper.get("unseen_ema3_rmse"), paper.get("unseen_ema3_direction_mae_deg")) if tau == 3.0 else (None, None)
            rows_.append([f"EMA tau={tau:g} s", fmt(m["per_window_vector_rmse"]), fmt(m["direction_mae_deg"], 1), fmt(pr[0]), fmt(pr[1], 1)])
        md += [
            f"### Unseen LHS design (`{results['unseen_data']['path']}`, seed {results['unseen_data']['seed']}, "
            f"{results['unseen_data']['cases']} cases, all flights): raw vs filtered", "",
            table(["estimate", "per-window RMSE (m/s)", "dir. MAE (deg)", "paper RMSE", "paper dir. MAE"], rows_), "",
        ]  # fmt: skip
    md += ["Figures:", ""] + [f"![{k}]({rel(v)})" for k, v in figs.items()] + [""]
    md.append(f"All numbers: `{json_path}`.")
    Path(args.md).parent.mkdir(parents=True, exist_ok=True)
    replace_section(Path(args.md), regime, "\n".join(md))
    results["wall_time_s"] = round(time.perf_counter() - t_start, 1)
    tmp = json_path.with_name(f".{json_path.name}.tmp")
    tmp.write_text(json.dumps(results, indent=1, default=float) + "\n")
    tmp.replace(json_path)

    if args.update_checkpoint:
        bundle.ema_tau_s = float(tau_best) if tau_best > 0 else bundle.ema_tau_s
        bundle.manifest["evaluation"] = {
            "command": results["command"],
            "stride": args.stride,
            "val_best_tau_s": tau_best,
            "test_raw": t["summary"],
            "test_ema": results["test_ema"],
            **({"unseen_raw": results["unseen"]["summary"], "unseen_ema": results["unseen_ema"]} if unseen is not None else {}),
        }
        bundle.save(ckpt)
        print(f"updated {ckpt}: ema_tau_s={bundle.ema_tau_s:g}, evaluation metrics in its manifest")
    s = t["summary"]
    print(
        f"test: per-window {s['per_window_vector_rmse']:.3f} m/s, per-flight {s.get('per_flight_vector_rmse', float('nan')):.3f} m/s, "
        f"component-mean {s['component_mean_rmse']:.3f} m/s, direction MAE {s['direction_mae_deg']:.2f} deg, corr {s['corr_n']:.4f}/{s['corr_e']:.4f}, "
        f"vector skill {s['vector_skill']:.3f}, speed skill {s['speed_skill']:.3f}; val best tau {tau_best:g} s"
    )
    print(f"wrote {args.md} ({regime} section), {json_path}, {len(figs)} figures in {fig_dir}; {results['wall_time_s']} s")


if __name__ == "__main__":
    main()
