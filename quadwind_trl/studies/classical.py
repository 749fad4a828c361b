"""The classical controllers on the test sweeps (``recipes/ablation.py --controllers ...``,
``results/classical/ablation_<sweep>.json``), each paired with the PD flown beside it, next to the
wind-aware policy's rows of the paired ablation."""
from __future__ import annotations

from ..regimes import CLASSICAL_LABEL
from .section import ReportContext, Section
from .tables import SWEEP_TITLES, ci, in_sweep_order, seed_stats


def _by_wind_gain(episodes: dict, name: str) -> dict[float, float]:
    """``{wind level: xy RMSE reduction of controller name against PD, %}`` from an episode table."""
    winds = episodes["wind_speed_ref_m_s"]
    out = {}
    for level in sorted(set(winds)):
        rows = [i for i, w in enumerate(winds) if w == level]
        pd = sum(episodes["pd_rmse_xy"][i] for i in rows)
        out[level] = 100.0 * (1.0 - sum(episodes[f"{name}_rmse_xy"][i] for i in rows) / pd)
    return out


def classical_sweeps_section(classical: dict[str, dict], ablations: dict[str, dict],
                             seeds: dict[str, dict[str, dict]]) -> str:
    """The classical controllers on the test sweeps (``results/classical/ablation_<sweep>.json``,
    each paired with the PD it flew beside) next to the wind-aware policy's rows of the paired
    ablation (the shipped policy, and the seeds' range)."""
    lines = ["### On the test sweeps", "",
             "Each classical row is paired with the PD flown beside it on the same episodes (bootstrap 95 % interval);",
             "the RL rows are the paired ablation's (the shipped policy, and the mean and range of seeds 0-4), each",
             "paired with its own PD flight of the same episodes: where the files come from processors of another",
             "vector instruction set, PD's mean RMSE differs in the last digits (both are given).", ""]
    for sweep, result in in_sweep_order(classical):
        names = [c for c in result["controllers"] if c != "pd"]
        rl = ablations.get(sweep)
        xy, z = result["rmse_xy"], result["rmse_z"]
        pd_means = f"PD xy {xy['distribution']['pd']['mean']:.3f} m here"
        if rl is not None:
            pd_means += f", {rl['rmse_xy']['distribution']['pd']['mean']:.3f} m in the RL file"
        lines += [f"#### {SWEEP_TITLES.get(sweep, sweep)} sweep ({result['episodes']} episodes)", "",
                  f"`{result['command']}` at `{result['git_commit']}`; {pd_means}.", "",
                  "| controller | xy vs PD (95 % CI) | wins | z vs PD (95 % CI) | worst xy (m) | crashed |",
                  "|---|---|---|---|---|---|"]
        for name in names:
            lines.append(f"| {CLASSICAL_LABEL.get(name, name)} | {xy[name]['improvement']:+.1f} % ({ci(xy[name])}) | "
                         f"{xy[name]['wins']}/{xy[name]['n']} | {z[name]['improvement']:+.1f} % ({ci(z[name])}) | "
                         f"{xy['worst'][name]:.3f} | {result['crashed'][name]} |")
        if rl is not None and "aware" in rl["rmse_xy"]:
            a, az = rl["rmse_xy"]["aware"], rl["rmse_z"]["aware"]
            lines.append(f"| wind-aware RL, shipped | {a['improvement']:+.1f} % ({ci(a)}) | {a['wins']}/{a['n']} | "
                         f"{az['improvement']:+.1f} % ({ci(az)}) | {rl['rmse_xy']['worst']['aware']:.3f} | "
                         f"{rl['crashed']['aware']} |")
            per_seed = [r[sweep] for r in seeds.values() if sweep in r and "aware" in r[sweep]["rmse_xy"]]
            if per_seed:
                gx = [r["rmse_xy"]["aware"]["improvement"] for r in per_seed]
                gz = [r["rmse_z"]["aware"]["improvement"] for r in per_seed]
                lines.append(f"| wind-aware RL, {len(per_seed)} seeds: mean (range) | {seed_stats(gx)} | | "
                             f"{seed_stats(gz)} | {max(r['rmse_xy']['worst']['aware'] for r in per_seed):.3f} (largest) | "
                             f"{sum(r['crashed']['aware'] for r in per_seed)} (sum) |")
        ff = [law for law in ("pd_ff", "pid_ff") if law in result["rmse_xy"].get("feedforward", {})]
        for law in ff:
            block = xy["feedforward"][law]
            parts = [f"{label} {block[key]['improvement']:+.1f} % ({ci(block[key])}), {block[key]['wins']}/{block[key]['n']}"
                     for key, label in (("estimate_value", "the estimate against zero"),
                                        ("oracle_value", "the true wind against the estimate")) if key in block]
            lines += ["", f"What the estimate is worth to {CLASSICAL_LABEL[law]} (xy): " + "; ".join(parts) + "."]
        winds = _by_wind_gain(result["episodes_table"], names[0])
        lines += ["", "xy RMSE reduction against PD by wind level (m/s): | " + " | ".join(f"{w:g}" for w in winds) + " |",
                  "|---|" + "---|" * len(winds)]
        for name in names:
            gains = _by_wind_gain(result["episodes_table"], name)
            lines.append(f"| {CLASSICAL_LABEL.get(name, name)} | " + " | ".join(f"{g:+.1f} %" for g in gains.values()) + " |")
        if rl is not None and "aware" in rl["rmse_xy"]:
            gains = _by_wind_gain(rl["episodes_table"], "aware")
            lines.append("| wind-aware RL, shipped | " + " | ".join(f"{g:+.1f} %" for g in gains.values()) + " |")
        lines.append("")
    return "\n".join(lines)


def _render(ctx: ReportContext) -> str | None:
    return classical_sweeps_section(ctx.classical, ctx.ablations, ctx.seeds) if ctx.classical else None


SECTION = Section("classical_sweeps", "On the test sweeps", ("results/classical/ablation_*.json",), _render)
