"""The estimation figures (error bars by group, example time series), drawn from the results of
:func:`quadwind_trl.evaluation.estimation_run.run_estimation` (matplotlib, PNG)."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402

from ..envs.trajectories import trajectory_name  # noqa: E402
from .estimation import FlightSequences  # noqa: E402
from .estimation_run import EstimationRun  # noqa: E402


def error_bars_figure(groups: dict[str, dict], xlabel: str, title: str, path: Path) -> None:
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
    return rows, [trajectory_name(seq.traj_id[i]) for i in rows]


def estimation_figures(run: EstimationRun, fig_dir: Path) -> tuple[dict[str, Path], int]:
    """The regime's figures in ``fig_dir``: ``({name: path}, example wind case)``. Error vs speed
    (and, vertical, vs altitude) on the test cases; an example case's time series (vertical: on
    the unseen design if evaluated, with the deployed-tau EMA)."""
    regime, results, deployed = run.regime, run.results, run.tau_best
    figs = {}
    tag = f"estimation_{regime}"
    figs["speed"] = fig_dir / f"{tag}_error_vs_speed.png"
    error_bars_figure(results["test"]["by_speed"], "true wind speed (m/s)", f"{regime} estimator, held-out test cases: error vs wind speed", figs["speed"])
    if regime == "vertical":
        figs["altitude"] = fig_dir / f"{tag}_error_vs_altitude.png"
        error_bars_figure(results["test"]["by_altitude"], "altitude band (m)", "vertical estimator, held-out test cases: error vs altitude", figs["altitude"])
    use_unseen = regime == "vertical" and run.unseen is not None
    src, src_name = (run.unseen, "unseen") if use_unseen else (run.test, "held-out test")
    src_f = (run.unseen_filtered if use_unseen else run.test_filtered).get(deployed)
    case = example_case(src, 3.8 if regime == "horizontal" else None)
    rows, labels = case_rows(src, case)
    figs["timeseries"] = fig_dir / f"{tag}_timeseries.png"
    timeseries_figure(
        src, rows, labels, src_f if regime == "vertical" else None, deployed,
        f"{regime} estimation, {src_name} wind case {case}", figs["timeseries"],
    )  # fmt: skip
    return figs, case
