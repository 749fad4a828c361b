"""Every evaluated regime against the flight envelope: the airspeed each sweep cell and
training design demands (:func:`~quadwind_trl.evaluation.envelope.airspeed_demand`), the margin to
the envelope of :mod:`quadwind_trl.envs.envelope`, and a simulator check that the PD stops holding
position where the envelope says (``recipes/flight_envelope.py``).
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402

from ..config import EnvConfig  # noqa: E402
from ..envs.envelope import FlightEnvelope  # noqa: E402
from ..envs.scenarios import RegimeRanges, make_scenarios, sample_regimes, wind_ceiling_bound  # noqa: E402
from ..envs.simulator import QuadSimulator  # noqa: E402
from ..evaluation.envelope import GUST_SIGMAS, airspeed_demand, pattern_speed  # noqa: E402
from ..regimes import EvalSweep  # noqa: E402

DESIGN_SAMPLES = 20_000  # Monte Carlo draws per training design (fractions to +-0.7 %)
DESIGN_SAMPLE_SEED = 4242  # not a design seed: only fractions of a range are estimated with it


def shear_points(ranges: RegimeRanges) -> dict[str, float]:
    """The median (the designs draw shear uniformly) and the worst (largest) shear of a range."""
    low, high = ranges.shear_alpha
    return {"median": 0.5 * (low + high), "worst": high}


def _altitude(ranges: RegimeRanges) -> float:
    return ranges.top_altitude_m if ranges.altitude_m is None else 0.5 * sum(ranges.altitude_m)


def sweep_cells(sweep: EvalSweep, regime: str, cfg: EnvConfig, envelope: FlightEnvelope) -> list[dict]:
    """One row per (wind speed, intensity) cell: demand and margin (envelope minus demand, positive
    inside) at the median and worst shear of the sweep's range, and how many of the cell's wind
    cases, at their own drawn shear, demand more than the envelope."""
    speed, limit = pattern_speed(cfg, regime), envelope.airspeed_m_s
    cases = sweep.scenarios()[:: len(sweep.trajectories)]  # one row per wind case
    drawn = airspeed_demand(cases, cfg, speed)
    rows = []
    for u in sweep.wind_speeds:
        for intensity in sweep.intensities:
            row = {"sweep": sweep.name, "wind_speed_m_s": u, "intensity": intensity, "altitude_m": _altitude(sweep.ranges)}
            for name, alpha in shear_points(sweep.ranges).items():
                sc = make_scenarios(1, wind_speed_ref_m_s=u, turb_intensity=intensity, shear_alpha=alpha,
                                    altitude_m=row["altitude_m"], traj_id=sweep.trajectories[0])
                d = {k: v.item() for k, v in airspeed_demand(sc, cfg, speed).items()}
                row[name] = {"shear_alpha": alpha, **d, "margin": limit - d["demand"], "sustained_margin": limit - d["sustained"]}
            in_cell = (cases["wind_speed_ref_m_s"] == u) & (cases["turb_intensity"] == intensity)
            row["cases"] = int(in_cell.sum())
            row["cases_beyond"] = int((drawn["demand"][in_cell] > limit).sum())
            row["cases_sustained_beyond"] = int((drawn["sustained"][in_cell] > limit).sum())
            rows.append(row)
    return rows


def design_row(name: str, ranges: RegimeRanges, regime: str, cfg: EnvConfig, envelope: FlightEnvelope,
               samples: int = DESIGN_SAMPLES) -> dict:
    """A training design against the envelope: its strongest corner (the top wind speed the design
    allows at the flight altitude, the top intensity) at the median and worst shear, and the
    fraction of its episodes (Monte Carlo over the design) whose demand lies beyond."""
    speed, limit = pattern_speed(cfg, regime), envelope.airspeed_m_s
    row = {"design": name, "wind_speed_m_s": list(ranges.wind_speed_m_s), "intensity": list(ranges.intensity),
           "shear_alpha": list(ranges.shear_alpha), "altitude_m": ranges.altitude_m or ranges.top_altitude_m}
    for point, alpha in shear_points(ranges).items():
        z = _altitude(ranges)
        u_top = wind_ceiling_bound(ranges, torch.tensor([alpha], dtype=torch.float64), torch.tensor([z], dtype=torch.float64)).item()
        sc = make_scenarios(1, wind_speed_ref_m_s=u_top, turb_intensity=ranges.intensity[1], shear_alpha=alpha, altitude_m=z)
        d = {k: v.item() for k, v in airspeed_demand(sc, cfg, speed).items()}
        row[point] = {"shear_alpha": alpha, "wind_speed_m_s": u_top, **d, "margin": limit - d["demand"],
                      "sustained_margin": limit - d["sustained"]}
    drawn = airspeed_demand(sample_regimes(samples, ranges, DESIGN_SAMPLE_SEED), cfg, speed)
    row["fraction_beyond"] = (drawn["demand"] > limit).double().mean().item()
    row["fraction_sustained_beyond"] = (drawn["sustained"] > limit).double().mean().item()
    return row


def edge_wind_speed(ranges: RegimeRanges, regime: str, cfg: EnvConfig, envelope: FlightEnvelope,
                    intensities: tuple[float, ...]) -> list[dict]:
    """Where the envelope's edge runs through a design: the lowest 10 m wind speed U (m/s, to
    0.01) whose sustained demand, and whose gust demand at each of ``intensities``, exceeds the
    envelope, at the median and worst shear; ``inf`` when the capped wind never gets there."""
    speed, limit = pattern_speed(cfg, regime), envelope.airspeed_m_s
    u = torch.arange(0.0, 40.0, 0.01, dtype=torch.float64)
    first = lambda beyond: u[beyond][0].item() if beyond.any() else math.inf  # noqa: E731
    rows = []
    for point, alpha in shear_points(ranges).items():
        row = {"shear": point, "shear_alpha": alpha}
        for intensity in (0.0, *intensities):
            sc = make_scenarios(u.numel(), wind_speed_ref_m_s=u, turb_intensity=intensity, shear_alpha=alpha,
                                altitude_m=_altitude(ranges))
            row["sustained" if intensity == 0.0 else f"I={intensity:g}"] = first(airspeed_demand(sc, cfg, speed)["demand"] > limit)
        rows.append(row)
    return rows


def edge_table(rows: list[dict]) -> str:
    """:func:`edge_wind_speed` rows as a markdown table."""
    keys = [k for k in rows[0] if k not in ("shear", "shear_alpha")]
    lines = ["| shear | " + " | ".join(f"U at edge, {k}" for k in keys) + " |", "|---|" + "---|" * len(keys)]
    for r in rows:
        lines.append(f"| {r['shear']} ({r['shear_alpha']:.3f}) | " + " | ".join(f"{r[k]:.2f}" for k in keys) + " |")
    return "\n".join(lines)


def steady_wind_config(cfg: EnvConfig, cap_m_s: float = 60.0) -> EnvConfig:
    """``cfg`` for the hold check: the PD on true state, no turbulence or sensors, the mean-wind
    cap raised above the winds flown."""
    return replace(cfg, sensors=replace(cfg.sensors, enabled=False), turbulence=replace(cfg.turbulence, enabled=False),
                   controller=replace(cfg.controller, feedback="truth"), wind=replace(cfg.wind, max_horizontal_wind_m_s=cap_m_s))


def hold_check(cfg: EnvConfig, winds: torch.Tensor, seconds: float = 25.0, window_s: float = 5.0,
               altitude_m: float = 100.0) -> dict[str, list[float]]:
    """The PD hovering (pattern ``hover``) in steady uniform winds ``winds`` (m/s, from the west):
    its downwind drift speed over the last ``window_s`` of ``seconds``, the airspeed it holds
    (wind minus drift: the envelope, once it drifts) and its altitude change (m)."""
    sim = QuadSimulator(steady_wind_config(cfg))
    n = winds.numel()
    sc = make_scenarios(n, traj_id="hover", altitude_m=altitude_m, start_step=-1, shear_alpha=0.0,
                        wind_speed_ref_m_s=winds, wind_dir_deg=270.0)
    params, state = sim.initial(sc)
    action = torch.zeros(n, 4)
    steps, window = round(seconds / sim.control_dt), round(window_s / sim.control_dt)
    for k in range(steps):
        if k == steps - window:
            x_start = state["body", "pos"][:, 0].clone()
        state = sim.step(params, state, action)
    drift = (state["body", "pos"][:, 0] - x_start) / window_s
    return {"wind_m_s": winds.tolist(), "drift_m_s": drift.tolist(), "airspeed_held_m_s": (winds - drift).tolist(),
            "altitude_change_m": (state["body", "pos"][:, 2] - altitude_m).tolist()}


def first_not_held(check: dict[str, list[float]], tolerance_m_s: float = 0.05) -> float:
    """The lowest wind (m/s) at which the PD drifts downwind faster than ``tolerance_m_s``."""
    return min((w for w, d in zip(check["wind_m_s"], check["drift_m_s"]) if d > tolerance_m_s), default=math.inf)


def envelope_figure(rows: list[dict], envelope: FlightEnvelope, tilt_only: float, path: Path,
                    marks: tuple[tuple[float, float, str], ...] = ()) -> Path:
    """Demanded airspeed against wind speed for the level-flight sweeps (median and worst shear,
    the gust band from sustained to gust demand at the median shear) beside the envelope's lines;
    ``marks``: (U, demand, label) points to show, e.g. observed flights."""
    fig, ax = plt.subplots(figsize=(10.0, 4.8))
    level = [r for r in rows if r["sweep"] != "vertical"]
    intensities = sorted({r["intensity"] for r in level})
    cmap = plt.get_cmap("viridis", len(intensities) + 1)
    for shear, style in (("median", "-"), ("worst", "--")):
        by_u = {}
        for r in level:
            by_u.setdefault(r["wind_speed_m_s"], []).append(r)
        us = sorted(by_u)
        sustained = [by_u[u][0][shear]["sustained"] for u in us]
        ax.plot(us, sustained, style, color="k", lw=1.5, label=f"sustained, {shear} shear ({level[0][shear]['shear_alpha']:.2f})")
        for i, intensity in enumerate(intensities):
            cells = sorted((r for r in level if r["intensity"] == intensity), key=lambda r: r["wind_speed_m_s"])
            x = [r["wind_speed_m_s"] for r in cells]
            y = [r[shear]["demand"] for r in cells]
            label = f"+{GUST_SIGMAS:g} sigma_u, I = {intensity:g}" if shear == "median" else None
            ax.plot(x, y, style, marker="o", ms=3, color=cmap(i), label=label)
        if shear == "median":
            ax.fill_between(us, sustained, [max(r[shear]["demand"] for r in by_u[u]) for u in us], color="0.85", zorder=0)
    ax.axhline(envelope.airspeed_m_s, color="tab:red", lw=2, label=f"envelope ({envelope.binding}-limited) {envelope.airspeed_m_s:.1f} m/s")
    ax.axhline(tilt_only, color="tab:red", lw=1, ls=":", label=f"tilt limit {envelope.max_tilt_deg:g} deg alone {tilt_only:.1f} m/s")
    for u, demand, label in marks:
        ax.plot([u], [demand], "x", color="tab:red", ms=8, mew=2)
        ax.annotate(label, (u, demand), textcoords="offset points", xytext=(-8, 8), ha="right", fontsize=7)
    ood_from = max(r["wind_speed_m_s"] for r in level if r["sweep"] == "horizontal") + 0.5
    ax.axvspan(ood_from, max(r["wind_speed_m_s"] for r in level) + 0.5, color="tab:red", alpha=0.06, lw=0)
    ax.text(ood_from + 0.2, ax.get_ylim()[0] + 0.5, "OOD sweep", fontsize=8)
    ax.set_xlabel("wind speed at 10 m, U (m/s)")
    ax.set_ylabel(f"airspeed demanded at {level[0]['altitude_m']:g} m (m/s)")
    ax.set_title("Level-flight sweeps against the flight envelope (upwind leg)")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.grid(alpha=0.3)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path


def _pair(row: dict, key: str, fmt: str = "{:+.1f}") -> str:
    return " / ".join(fmt.format(row[s][key]) for s in ("median", "worst"))


def sweep_table(rows: list[dict]) -> str:
    """The sweep cells as a markdown table (each pair: median / worst shear)."""
    lines = ["| sweep | U (m/s) | I | shear | mean wind (m/s) | sigma_u | demand (m/s) | margin | sustained margin | cases beyond |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['sweep']} | {r['wind_speed_m_s']:g} | {r['intensity']:g} | {_pair(r, 'shear_alpha', '{:.3f}')} | "
                     f"{_pair(r, 'mean_wind', '{:.1f}')} | {_pair(r, 'sigma_u', '{:.1f}')} | {_pair(r, 'demand', '{:.1f}')} | "
                     f"{_pair(r, 'margin')} | {_pair(r, 'sustained_margin')} | "
                     f"{r['cases_beyond']}/{r['cases']} ({r['cases_sustained_beyond']} sustained) |")
    return "\n".join(lines)


def design_table(rows: list[dict]) -> str:
    """The training designs as a markdown table (corner: top wind and intensity; median / worst shear)."""
    lines = ["| design | altitude (m) | U (m/s) | I | shear | corner U (m/s) | corner demand (m/s) | corner margin | "
             "corner sustained margin | episodes beyond (sustained) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        span = lambda v: f"{v[0]:g}-{v[1]:g}"  # noqa: E731
        alt = span(r["altitude_m"]) if isinstance(r["altitude_m"], (list, tuple)) else f"top {r['altitude_m']:g}"
        lines.append(f"| {r['design']} | {alt} | {span(r['wind_speed_m_s'])} | {span(r['intensity'])} | {span(r['shear_alpha'])} | "
                     f"{_pair(r, 'wind_speed_m_s', '{:.1f}')} | {_pair(r, 'demand', '{:.1f}')} | {_pair(r, 'margin')} | "
                     f"{_pair(r, 'sustained_margin')} | {100 * r['fraction_beyond']:.1f} % "
                     f"({100 * r['fraction_sustained_beyond']:.1f} %) |")
    return "\n".join(lines)
