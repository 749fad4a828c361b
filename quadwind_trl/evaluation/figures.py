"""The paper's tracking figures, drawn from an ablation's results, and the PPO runs' learning curves
(matplotlib, PNG). The studies draw their own figures with these colours, labels and :func:`save_figure`."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from tensordict import TensorDictBase  # noqa: E402

from ..envs.runner import FlightResults  # noqa: E402
from ..envs.trajectories import trajectory_id, trajectory_name  # noqa: E402
from ._moved import moved  # noqa: E402

COLORS = {"pd": "tab:red", "blind": "tab:orange", "aware": "tab:blue", "oracle": "tab:green", "trained_blind": "tab:purple"}
LABELS = {"pd": "PD baseline", "blind": "wind-blind RL", "aware": "wind-aware RL", "oracle": "true-wind oracle",
          "trained_blind": "RL trained wind-blind"}


def save_figure(fig, path: Path) -> Path:
    """Write ``fig`` to ``path`` as PNG (its folder made) and close it; returns ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path


def _table(summary: dict) -> dict[str, np.ndarray]:
    """The per-episode columns, trajectories by name (results written before names were stored
    hold ``traj_id``, the ids of the built-in patterns, which the registry keeps)."""
    table = dict(summary["episodes_table"])
    if "trajectory" not in table:
        table["trajectory"] = [trajectory_name(i) for i in table.pop("traj_id")]
    return {k: np.asarray(v) for k, v in table.items()}


def _trajectories(t: dict[str, np.ndarray]) -> list[str]:
    """The table's trajectories in the order they first appear (the sweep's order)."""
    return list(dict.fromkeys(t["trajectory"].tolist()))


def _by_wind(summary: dict, metric: str) -> tuple[np.ndarray, dict]:
    rows = summary[metric]["by_wind"]
    speeds = np.array(sorted(float(k) for k in rows))
    return speeds, {s: rows[f"{s:g}"] for s in speeds}


def scatter_and_improvement(summary: dict, path: Path, metric: str = "rmse_xy") -> Path:
    """(a) per-condition wind-aware vs PD RMSE; (b) relative improvement vs wind per intensity."""
    t = _table(summary)
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4.2))
    pd_, aw = t[f"pd_{metric}"], t[f"aware_{metric}"]
    sc = a.scatter(pd_, aw, c=t["wind_speed_ref_m_s"], cmap="viridis", s=14)
    top = max(pd_.max(), aw.max()) * 1.05
    a.plot([0, top], [0, top], "k--", lw=0.8)
    a.set(xlabel="PD RMSE (m)", ylabel="wind-aware RL RMSE (m)", xscale="log", yscale="log",
          title=f"{(aw < pd_).sum()}/{len(pd_)} episodes below the diagonal")
    fig.colorbar(sc, ax=a, label="U (m/s)")
    for inten in np.unique(t["turb_intensity"]):
        m = np.isclose(t["turb_intensity"], inten)
        speeds = np.unique(t["wind_speed_ref_m_s"][m])
        impr = [100 * (1 - aw[m & (t["wind_speed_ref_m_s"] == s)].mean() / pd_[m & (t["wind_speed_ref_m_s"] == s)].mean()) for s in speeds]
        b.plot(speeds, impr, "o-", label=f"intensity {inten:.2f}")
    b.set(xlabel="mean wind U (m/s)", ylabel="RMSE reduction vs PD (%)", title="improvement by wind level")
    b.legend()
    b.grid(alpha=0.3)
    return save_figure(fig, path)


def decomposition(summary: dict, path: Path, metric: str = "rmse_xy") -> Path:
    """Four panels: RMSE by wind for the controllers; stacked kinematic / perception shares;
    perception share of the improvement; per-trajectory RMSE at the strongest wind."""
    speeds, rows = _by_wind(summary, metric)
    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    a = ax[0, 0]
    for name in ("pd", "blind", "aware"):
        a.plot(speeds, [rows[s][name] for s in speeds], "o-", color=COLORS[name], label=LABELS[name])
    for name in ("oracle", "trained_blind"):
        if name in rows[speeds[0]]:
            a.plot(speeds, [rows[s][name] for s in speeds], "s--", color=COLORS[name], label=LABELS[name])
    a.fill_between(speeds, [rows[s]["pd"] for s in speeds], [rows[s]["blind"] for s in speeds], color="tab:orange", alpha=0.15)
    a.fill_between(speeds, [rows[s]["blind"] for s in speeds], [rows[s]["aware"] for s in speeds], color="tab:blue", alpha=0.15)
    a.set(xlabel="U (m/s)", ylabel="mean RMSE (m)", title="controllers by wind level")
    a.legend()
    b = ax[0, 1]
    kin = np.array([100 * rows[s]["kinematic"] / rows[s]["pd"] for s in speeds])
    perc = np.array([100 * rows[s]["perception"] / rows[s]["pd"] for s in speeds])
    width = 0.8 * (speeds[1] - speeds[0]) if len(speeds) > 1 else 1.0
    b.bar(speeds, kin, width, color="tab:orange", label="kinematic")
    b.bar(speeds, perc, width, bottom=kin, color="tab:blue", label="wind perception")
    b.set(xlabel="U (m/s)", ylabel="reduction of PD RMSE (%)", title="stacked components")
    b.legend()
    c = ax[1, 0]
    c.plot(speeds, [rows[s]["perception_share"] for s in speeds], "o-", color="tab:blue")
    c.axhline(0, color="k", lw=0.8)
    c.set(xlabel="U (m/s)", ylabel="perception share of the improvement (%)", title="wind-perception share")
    d = ax[1, 1]
    t = _table(summary)
    strongest = t["wind_speed_ref_m_s"] == t["wind_speed_ref_m_s"].max()
    names = _trajectories(t)
    for k, name in enumerate(("pd", "blind", "aware")):
        vals = [t[f"{name}_{metric}"][strongest & (t["trajectory"] == traj)].mean() for traj in names]
        d.bar(np.arange(len(names)) + (k - 1) * 0.27, vals, 0.27, color=COLORS[name], label=LABELS[name])
    d.set_xticks(np.arange(len(names)), names, rotation=20)
    d.set(ylabel="mean RMSE (m)", title=f"by trajectory at U = {t['wind_speed_ref_m_s'].max():g} m/s")
    d.legend()
    return save_figure(fig, path)


def _pick(scenarios: TensorDictBase, traj: str, wind: float) -> int:
    m = (scenarios["traj_id"] == trajectory_id(traj)) & (scenarios["wind_speed_ref_m_s"] == wind)
    rows = torch.nonzero(m).flatten()
    return int(rows[len(rows) // 2])


def _trace(res: FlightResults, row: int, pattern_only: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """True and reference positions of one flight at 10 Hz; ``pattern_only`` drops the climb of a
    fixed-altitude flight (the samples before the reference reaches its cruise altitude)."""
    keep = res.log["valid"][row]
    ref = res.log["ref_pos"][row]
    if pattern_only:
        keep = keep & (ref[:, 2] >= ref[keep][:, 2].max() - 1e-3)
    return res.log["truth", "pos"][row][keep].numpy(), ref[keep].numpy()


def trace_top_down(scenarios: TensorDictBase, results: dict[str, FlightResults], traj: str, wind: float, path: Path) -> Path:
    """The trace of the episode of ``traj`` in the middle of those at ``wind`` (:func:`trace_episode`)."""
    return trace_episode(results, _pick(scenarios, traj, wind), f"{traj}, U = {wind:g} m/s", path)


def trace_episode(results: dict[str, FlightResults], row: int, title: str, path: Path, wind_arrow: bool = False) -> Path:
    """(a) top-down path of PD and wind-aware RL against the reference; (b) horizontal error.
    ``wind_arrow`` adds (c): the mean wind the vehicle met, the turbulence-free wind at its
    position averaged over the pattern (shear and veer to the flight altitude are in it)."""
    fig, axes = plt.subplots(1, 3 if wind_arrow else 2, figsize=(13 if wind_arrow else 11, 4.5),
                             gridspec_kw={"width_ratios": [4, 4, 1] if wind_arrow else [1, 1]})
    a, b = axes[:2]
    _, ref = _trace(results["pd"], row, pattern_only=True)
    a.plot(ref[:, 0], ref[:, 1], "k--", lw=0.8, label="reference")
    for name in ("pd", "aware"):
        pos, ref = _trace(results[name], row, pattern_only=True)
        err = np.linalg.norm(pos[:, :2] - ref[:, :2], axis=-1)
        rmse = results[name].rmse_xy[row].item()
        a.plot(pos[:, 0], pos[:, 1], color=COLORS[name], lw=1, label=f"{LABELS[name]} (xy RMSE {rmse:.2f} m)")
        b.plot(np.arange(len(err)) / 10.0, err, color=COLORS[name], lw=0.8, label=LABELS[name])
    a.set(xlabel="east (m)", ylabel="north (m)", title=title)
    a.set_aspect("equal", adjustable="datalim")
    a.legend(fontsize=8)
    b.set(xlabel="time since the pattern start (s)", ylabel="horizontal error (m)", title="tracking error over the pattern")
    b.legend()
    if wind_arrow:
        _wind_arrow(axes[2], results["pd"], row)
    return save_figure(fig, path)


def _track_frame_error(pos: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal error split along the reference's direction of travel: (along-track, ahead
    positive; cross-track, left of the track positive), in m. The direction is the reference's own
    velocity, by central differences of its 10 Hz samples."""
    tangent = np.gradient(ref[:, :2], axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=-1, keepdims=True), 1e-9)
    err = pos[:, :2] - ref[:, :2]
    along = (err * tangent).sum(-1)
    cross = err[:, 1] * tangent[:, 0] - err[:, 0] * tangent[:, 1]
    return along, cross


def tracking_error_episode(results: dict[str, FlightResults], row: int, title: str, path: Path) -> Path:
    """One episode's tracking error at the scale it has: (a) PD's and wind-aware RL's positions in
    a frame that moves with the reference (along-track against cross-track error, equal axes, in
    m), (b) the horizontal error over time, (c) the mean wind. A top-down plot of the tracks
    cannot show this: a pattern spans hundreds of metres, the errors a fraction of one."""
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.6), gridspec_kw={"width_ratios": [4, 5, 1]})
    a, b = axes[:2]
    a.axhline(0.0, color="k", lw=0.6, ls="--")
    a.axvline(0.0, color="k", lw=0.6, ls="--")
    for name in ("pd", "aware"):
        pos, ref = _trace(results[name], row, pattern_only=True)
        along, cross = _track_frame_error(pos, ref)
        err = np.hypot(along, cross)
        rmse = results[name].rmse_xy[row].item()
        a.plot(along, cross, color=COLORS[name], lw=0.8, alpha=0.85, label=f"{LABELS[name]} (xy RMSE {rmse:.2f} m)")
        circle = plt.Circle((0.0, 0.0), rmse, fill=False, color=COLORS[name], lw=1.2, ls=":")
        a.add_patch(circle)
        b.plot(np.arange(len(err)) / 10.0, err, color=COLORS[name], lw=0.9, label=LABELS[name])
    a.plot([0.0], [0.0], "k+", ms=10, mew=1.5, label="reference (the origin of this frame)")
    a.set(xlabel="along-track error (m, ahead +)", ylabel="cross-track error (m, left +)",
          title="position in the frame of the reference\n(dotted circles: xy RMSE)")
    a.set_aspect("equal", adjustable="datalim")
    a.legend(fontsize=7, loc="upper left")
    b.set(xlabel="time since the pattern start (s)", ylabel="horizontal error (m)", title=title)
    b.set_ylim(bottom=0.0)
    b.legend(fontsize=8)
    _wind_arrow(axes[2], results["pd"], row)
    return save_figure(fig, path)


def _wind_arrow(a, res: FlightResults, row: int) -> None:
    """An arrow along the episode's mean wind, with its speed and meteorological direction."""
    valid = res.log["valid"][row]
    east, north = res.log["truth", "mean_wind"][row][valid][:, :2].double().mean(0).tolist()
    speed = float(np.hypot(east, north))
    blows_from = float(np.degrees(np.arctan2(-east, -north))) % 360.0  # clockwise from north
    # its own square panel: a track plot of equal aspect fixes its limits only when drawn
    a.set(xlim=(-1, 1), ylim=(-1, 1), aspect="equal")
    a.axis("off")
    u, v = 0.8 * east / speed, 0.8 * north / speed
    a.annotate("", xy=(u, v), xytext=(-u, -v), arrowprops={"arrowstyle": "-|>", "color": "tab:gray", "lw": 2.5})
    a.text(0, -1.1, f"mean wind\n{speed:.1f} m/s\nfrom {blows_from:.0f} deg", ha="center", va="top", fontsize=9)


def trace_3d(scenarios: TensorDictBase, results: dict[str, FlightResults], traj: str, wind: float, path: Path) -> Path:
    row = _pick(scenarios, traj, wind)
    fig = plt.figure(figsize=(7, 6))
    a = fig.add_subplot(projection="3d")
    pos, ref = _trace(results["pd"], row)
    a.plot(ref[:, 0], ref[:, 1], ref[:, 2], "k--", lw=0.7, label="reference")
    for name in ("pd", "aware"):
        pos, _ = _trace(results[name], row)
        a.plot(pos[:, 0], pos[:, 1], pos[:, 2], color=COLORS[name], lw=0.9,
               label=f"{LABELS[name]} (xy RMSE {results[name].rmse_xy[row].item():.2f} m)")
    a.set(xlabel="east (m)", ylabel="north (m)", zlabel="altitude (m)", title=f"{traj}, U_mean = {wind:g} m/s")
    a.legend(fontsize=8)
    return save_figure(fig, path)


def vertical_comparison(summary: dict, path: Path) -> Path:
    fig, ax = plt.subplots(1, 2, figsize=(10, 4.2))
    for a, metric, title in ((ax[0], "rmse_xy", "horizontal (xy)"), (ax[1], "rmse_z", "vertical (z)")):
        speeds, rows = _by_wind(summary, metric)
        for name in ("pd", "aware"):
            a.plot(speeds, [rows[s][name] for s in speeds], "o-", color=COLORS[name], label=LABELS[name])
        a.set(xlabel="U_mean (m/s)", ylabel="mean RMSE (m)", title=title)
        a.legend()
    return save_figure(fig, path)


def perception_share(summary: dict, path: Path, metric: str = "rmse_xy") -> Path:
    speeds, rows = _by_wind(summary, metric)
    fig, a = plt.subplots(figsize=(6, 4))
    a.plot(speeds, [rows[s]["perception_share"] for s in speeds], "o-", color="tab:blue")
    a.axhline(0, color="k", lw=0.8)
    a.set(xlabel="U_mean (m/s)", ylabel="perception share (%)", title="wind-perception share of the xy improvement")
    return save_figure(fig, path)


def ood_panel(summary: dict, path: Path, metric: str = "rmse_xy") -> Path:
    t = _table(summary)
    speeds = np.unique(t["wind_speed_ref_m_s"])
    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    a = ax[0, 0]
    for name in ("pd", "aware"):
        v = t[f"{name}_{metric}"]
        a.plot(speeds, [v[t["wind_speed_ref_m_s"] == s].mean() for s in speeds], "o-", color=COLORS[name], label=f"{LABELS[name]} mean")
        a.plot(speeds, [np.median(v[t["wind_speed_ref_m_s"] == s]) for s in speeds], "s--", color=COLORS[name], label=f"{LABELS[name]} median")
    a.set(xlabel="U (m/s)", ylabel="RMSE (m)", title="mean and median")
    a.legend(fontsize=8)
    b = ax[0, 1]
    pd_, aw = t[f"pd_{metric}"], t[f"aware_{metric}"]
    b.plot(speeds, [100 * (1 - aw[t["wind_speed_ref_m_s"] == s].mean() / pd_[t["wind_speed_ref_m_s"] == s].mean()) for s in speeds], "o-")
    b.set(xlabel="U (m/s)", ylabel="RMSE reduction (%)", title="improvement out of distribution")
    c = ax[1, 0]
    c.scatter(pd_, aw, s=14)
    top = max(pd_.max(), aw.max()) * 1.05
    c.plot([0, top], [0, top], "k--", lw=0.8)
    c.set(xlabel="PD RMSE (m)", ylabel="wind-aware RL RMSE (m)", xscale="log", yscale="log",
          title=f"{(aw < pd_).sum()}/{len(pd_)} below the diagonal")
    d = ax[1, 1]
    names = _trajectories(t)
    for k, name in enumerate(("pd", "aware")):
        d.bar(np.arange(len(names)) + (k - 0.5) * 0.4, [t[f"{name}_{metric}"][t["trajectory"] == traj].mean() for traj in names],
              0.4, color=COLORS[name], label=LABELS[name])
    d.set_xticks(np.arange(len(names)), names, rotation=20)
    d.set(ylabel="mean RMSE (m)", title="by trajectory")
    d.legend()
    return save_figure(fig, path)


def _csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A scalar's (frames, values). A resumed run logs again the frames its interrupted
    predecessor logged after the last checkpoint: the later row of each frame wins."""
    data = np.loadtxt(path, delimiter=",", ndmin=2)
    latest = dict(zip(data[:, 0].tolist(), data[:, 1].tolist()))
    frames = np.array(sorted(latest))
    return frames, np.array([latest[f] for f in frames])


def learning_curves(run_dirs: dict[str, Path], path: Path) -> Path:
    """PPO learning curves from the runs' CSV logs: training reward per step, the deterministic
    evaluation's improvement over PD, and the policy's exploration scale, against frames. One row
    per regime; runs of one kind (``ppo_<regime>[_trained_blind][_seed<k>]``) share a colour, so
    the seeds' spread shows as the spread of same-coloured lines."""
    regimes = [r for r in ("horizontal", "vertical") if any(f"_{r}" in name for name in run_dirs)]
    fig, axes = plt.subplots(len(regimes), 3, figsize=(14, 4 * len(regimes)), squeeze=False)
    colours: dict[str, str] = {}
    for name, run in run_dirs.items():
        regime = next(r for r in regimes if f"_{r}" in name)
        kind = name.removeprefix(f"ppo_{regime}").split("_seed")[0].strip("_") or "wind-aware"
        colour = colours.setdefault(kind, f"C{len(colours)}")
        ax = axes[regimes.index(regime)]
        style = {"color": colour, "label": name.removeprefix("ppo_"), "alpha": 0.8}
        scalars = Path(run) / "logs" / "ppo" / "scalars"
        frames, reward = _csv(scalars / "train" / "reward_mean.csv")
        window = max(1, len(reward) // 20)
        smooth = np.convolve(reward, np.ones(window) / window, mode="valid")
        ax[0].plot(frames[window - 1 :], smooth, **style)
        improvement = scalars / "eval" / "improvement_rmse_xy_pct.csv"
        if improvement.exists():
            f, v = _csv(improvement)
            ax[1].plot(f, v, "o-", **style)
        f, v = _csv(scalars / "train" / "action_scale.csv")
        ax[2].plot(f, v, **style)
    for regime, ax in zip(regimes, axes):
        ax[0].set(xlabel="frames", ylabel="reward per step (moving mean)", title=f"{regime}: training reward")
        ax[1].axhline(0, color="k", lw=0.8)
        ax[1].set(xlabel="frames", ylabel="xy RMSE reduction vs PD (%)", title=f"{regime}: deterministic evaluation")
        ax[2].set(xlabel="frames", ylabel="pre-tanh std", title=f"{regime}: exploration scale")
        for a in ax:
            a.legend(fontsize="small")
            a.grid(alpha=0.3)
    return save_figure(fig, path)


def pipeline_overview(path: Path) -> Path:
    """The two-stage pipeline (paper Fig. 1) as a block diagram of this library's pieces."""
    fig, a = plt.subplots(figsize=(12, 4.2))
    a.axis("off")
    boxes = {
        "sim": (0.02, 0.55, "QuadWindEnv\n6-DOF quadrotor, PD cascade\nvon Karman turbulence, sensors"),
        "feat": (0.27, 0.55, "FeatureRing\n10 Hz features (48 / 22 ch.)\n60-sample window"),
        "est": (0.52, 0.55, "WindEstimate\nfrozen attention-GRU\n+ spike-gated EMA (3 s)"),
        "obs": (0.52, 0.08, "PolicyObservation\n23 inputs incl. (w_N, w_E)\nWindZero: ablation"),
        "ppo": (0.77, 0.08, "PPO residual policy\nClipPPOLoss + GAE\nwrench added to PD"),
        "data": (0.27, 0.08, "flight datasets\nPD flights, LHS wind cases\nestimator training"),
    }
    for x, y, text in boxes.values():
        a.add_patch(plt.Rectangle((x, y), 0.2, 0.32, fill=True, color="#e8eef7", ec="#355c99", lw=1.2))
        a.text(x + 0.1, y + 0.16, text, ha="center", va="center", fontsize=9)

    def arrow(x0, y0, x1, y1, label=""):
        a.annotate("", xy=(x1, y1), xytext=(x0, y0), arrowprops={"arrowstyle": "->", "color": "#355c99", "lw": 1.3})
        if label:
            a.text((x0 + x1) / 2, (y0 + y1) / 2 + 0.02, label, ha="center", fontsize=8, color="#355c99")

    arrow(0.22, 0.71, 0.27, 0.71, "sensors")
    arrow(0.47, 0.71, 0.52, 0.71)
    arrow(0.62, 0.55, 0.62, 0.40, "wind_hat")
    arrow(0.72, 0.24, 0.77, 0.24)
    arrow(0.87, 0.40, 0.87, 0.88)
    a.annotate("", xy=(0.12, 0.88), xytext=(0.87, 0.88), arrowprops={"arrowstyle": "->", "color": "#355c99", "lw": 1.3})
    a.text(0.5, 0.91, "residual wrench (action)", ha="center", fontsize=8, color="#355c99")
    arrow(0.12, 0.55, 0.27, 0.30, "PD flights")
    arrow(0.47, 0.24, 0.56, 0.55, "trained weights")
    a.set(xlim=(0, 1), ylim=(0, 1), title="quadwind_trl: the two-stage wind-aware pipeline")
    return save_figure(fig, path)


# per sweep: the summary panels (drawer, file) and the trace at the strongest wind (drawer, trajectory, file)
# the controllers every ablation figure draws (the decomposition by wind level needs all three)
FIGURE_CONTROLLERS = ("pd", "blind", "aware")
ABLATION_FIGURES = {
    "horizontal": (((scatter_and_improvement, "tracking_horizontal.png"), (decomposition, "decomposition_horizontal.png")),
                   (trace_top_down, "lawnmower_h", "trace_lawnmower.png")),
    "vertical": (((vertical_comparison, "tracking_vertical.png"), (perception_share, "decomposition_vertical.png")),
                 (trace_3d, "figure8_3d", "trace_figure8_3d.png")),
    "ood": (((ood_panel, "ood.png"),), None),
}


def ablation_figures(sweep: str, scenarios: TensorDictBase, results: dict[str, FlightResults], summary: dict,
                     fig_dir: Path) -> list[Path]:
    """The ablation's figures of one sweep (``summarize_ablation``'s ``summary`` and the flights
    with their traces) in ``fig_dir``, as :data:`ABLATION_FIGURES` lists them. Returns the paths."""
    if sweep not in ABLATION_FIGURES:
        raise ValueError(f"sweep={sweep!r}; allowed: {sorted(ABLATION_FIGURES)}")
    panels, trace = ABLATION_FIGURES[sweep]
    paths = [draw(summary, fig_dir / name) for draw, name in panels]
    if trace is not None:
        draw_trace, traj, name = trace
        paths.append(draw_trace(scenarios, results, traj, float(scenarios["wind_speed_ref_m_s"].max()), fig_dir / name))
    return paths


# the studies' figures, moved beside their studies: the old names warn, for one release
__getattr__ = moved(__name__, {"diagnosis_episode": "quadwind_trl.studies.diagnosis",
                               "diagnosis_groups": "quadwind_trl.studies.diagnosis",
                               "perception_value": "quadwind_trl.studies.perception",
                               "results_summary": "quadwind_trl.studies.summary"})
