"""The PD baseline on the paper's evaluation sweeps beside the paper's PD columns, and PD with its
navigation error under each sensing preset (``recipes/pd_baseline.py``, ``results/pd_baseline*.json``):
the results page's calibration sections."""
from __future__ import annotations

from . import paper
from .section import ReportContext, Section
from .tables import by_number, headroom_pct


def _ratio(ours: float, theirs: float) -> str:
    return f"{ours / theirs:.2f}" if theirs else "-"


def pd_calibration_section(result: dict) -> str:
    """The PD baseline on the paper's sweeps, beside the paper's PD columns."""
    lines = ["## PD baseline on the paper's evaluation sweeps", ""]
    lines.append(f"Command: `{result['command']}` (commit `{result.get('git_commit')}`).")
    lines.append("RMSE against the true position, scored over each flight's pattern (after the climb for")
    lines.append("horizontal flights; the whole flight after arming for vertical ones). Ratio = ours / paper.")
    lines.append("How the cruise speed, the PD's navigation feedback, the sensor biases and the wind cap were")
    lines.append("set from these sweeps, and what each did, is in [simulator.md](simulator.md#calibrating-the-pd-baseline-against-the-paper).")
    lines.append(f"Sensing preset: `{result.get('sensors', 'legacy_walk')}`. *nav* = mean navigation error (the position the PD")
    lines.append("flies on against the true one), *headroom* = 1 - nav / ours: the largest improvement any controller could make.")
    lines.append("")
    sweeps = result["sweeps"]

    def headroom(tables: dict, group: str, key: str, axis: str = "xy") -> str:
        nav = tables.get(f"nav_rmse_{axis}")
        if nav is None:
            return "- | -"
        n = nav[group][key]["mean"] if key != "all" else nav["all"]["mean"]
        ours = tables[f"rmse_{axis}"][group][key]["mean"] if key != "all" else tables[f"rmse_{axis}"]["all"]["mean"]
        return f"{n:.3f} | {headroom_pct(n, ours):.0f} %"

    if "horizontal" in sweeps:
        tables = sweeps["horizontal"]["tables"]
        t = tables["rmse_xy"]
        lines += ["### Horizontal (225 episodes): PD RMSE by mean wind speed", "",
                  "| U (m/s) | ours mean +- std (m) | median | max | paper (m) | ratio | nav (m) | headroom |",
                  "|---|---|---|---|---|---|---|---|"]
        for key, row in by_number(t["by_wind"]):
            ref = paper.HORIZONTAL_BY_WIND[float(key)]["pd"]
            lines.append(f"| {key} | {row['mean']:.3f} +- {row['std']:.3f} | {row['median']:.3f} | {row['max']:.2f} | {ref:.3f} | "
                         f"{_ratio(row['mean'], ref)} | {headroom(tables, 'by_wind', key)} |")
        a = t["all"]
        ref = paper.HORIZONTAL_BY_WIND["all"]["pd"]
        lines.append(f"| all | {a['mean']:.3f} +- {a['std']:.3f} | {a['median']:.3f} | {a['max']:.2f} | {ref:.3f} | "
                     f"{_ratio(a['mean'], ref)} | {headroom(tables, 'all', 'all')} |")
        lines += ["", "### Horizontal: PD RMSE by trajectory", "", "| trajectory | ours (m) | paper (m) | ratio |", "|---|---|---|---|"]
        for name, row in t["by_trajectory"].items():
            ref = paper.HORIZONTAL_BY_TRAJECTORY[name]["pd"]
            lines.append(f"| `{name}` | {row['mean']:.3f} | {ref:.3f} | {_ratio(row['mean'], ref)} |")
        lines.append("")
    if "vertical" in sweeps:
        tables = sweeps["vertical"]["tables"]
        txy, tz = tables["rmse_xy"], tables["rmse_z"]
        z_ref = paper.TRACKING_STATS["vertical_z"]["pd"][0]
        lines += ["### Vertical (144 episodes): PD horizontal (xy) RMSE by mean wind speed", "",
                  "| U_mean (m/s) | ours xy mean +- std (m) | paper xy (m) | ratio | nav xy (m) | headroom xy | ours z (m) | "
                  f"ratio z (paper {z_ref:.2f}) | nav z (m) | headroom z |", "|---|---|---|---|---|---|---|---|---|---|"]
        for key, row in by_number(txy["by_wind"]):
            ref = paper.VERTICAL_BY_WIND[float(key)]["pd"]
            z = tz["by_wind"][key]["mean"]
            lines.append(f"| {key} | {row['mean']:.3f} +- {row['std']:.3f} | {ref:.3f} | {_ratio(row['mean'], ref)} | "
                         f"{headroom(tables, 'by_wind', key)} | {z:.3f} | {_ratio(z, z_ref)} | {headroom(tables, 'by_wind', key, 'z')} |")
        a, az = txy["all"], tz["all"]
        lines.append(f"| all | {a['mean']:.3f} +- {a['std']:.3f} | {paper.VERTICAL_BY_WIND['all']['pd']:.3f} | "
                     f"{_ratio(a['mean'], paper.VERTICAL_BY_WIND['all']['pd'])} | {headroom(tables, 'all', 'all')} | "
                     f"{az['mean']:.3f} | {_ratio(az['mean'], z_ref)} | {headroom(tables, 'all', 'all', 'z')} |")
        lines.append("")
    if "ood" in sweeps:
        t = sweeps["ood"]["tables"]["rmse_xy"]
        a = t["all"]
        lines += ["### Out of distribution (90 episodes, U = 13-15 m/s): PD", "",
                  "| U (m/s) | ours mean (m) | median | max |", "|---|---|---|---|"]
        for key, row in by_number(t["by_wind"]):
            lines.append(f"| {key} | {row['mean']:.3f} | {row['median']:.3f} | {row['max']:.2f} |")
        lines.append(f"| all | {a['mean']:.3f} | {a['median']:.3f} | {a['max']:.2f} |")
        lines.append(f"\nPaper: PD mean {paper.OOD['pd_mean']} m, worst case {paper.OOD['pd_worst']} m "
                     f"(lawnmower); ours: mean {a['mean']:.2f} m (ratio {_ratio(a['mean'], paper.OOD['pd_mean'])}), "
                     f"worst {a['max']:.1f} m; lawnmower mean {t['by_trajectory'].get('lawnmower_h', {}).get('mean', float('nan')):.2f} m "
                     f"(paper 13.96 m).")
        lines.append("Out of distribution the PD fails in the paper's way: error rising with wind, means far above")
        lines.append("medians because a few episodes are blown off track when gusts push the upwind airspeed past")
        mower = t["by_trajectory"].get("lawnmower_h", {}).get("mean", float("nan"))
        lines.append("the 30.5 m/s a 35-degree tilt can hold. The paper's collapse is stronger (mean "
                     f"{paper.OOD['pd_mean'] / a['mean']:.1f}x ours, worst case {paper.OOD['pd_worst'] / a['max']:.1f}x, "
                     f"lawnmower {13.96 / mower:.1f}x); the paper's pattern geometry is unknown, and one 47 m")
        lines.append("episode moves a 90-episode mean by 0.5 m.")
        lines.append("")
    return "\n".join(lines)


def sensing_presets_section(results: dict[str, dict]) -> str:
    """PD and its navigation error on every sweep under each sensing preset (``results``: preset
    name -> a ``recipes/pd_baseline.py`` result file flown with ``--sensors`` that preset)."""
    lines = ["## PD and navigation error under each sensing preset", "",
             "The same sweeps flown with the receiver class changed (`recipes/pd_baseline.py --sensors <preset>`);",
             "*nav* = mean navigation error, *headroom* = 1 - nav / PD. The commands and commits:", ""]
    lines += [f"* `{name}`: `{r['command']}` (commit `{r.get('git_commit')}`)" for name, r in results.items()]
    lines += ["", "| preset | sweep | PD xy (m) | nav xy (m) | headroom xy | PD z (m) | nav z (m) | headroom z |",
              "|---|---|---|---|---|---|---|---|"]
    for name, r in results.items():
        for sweep, block in r["sweeps"].items():
            t = block["tables"]
            cells = []
            for axis in ("xy", "z"):
                pd_, nav = t[f"rmse_{axis}"]["all"]["mean"], t[f"nav_rmse_{axis}"]["all"]["mean"]
                cells.append(f"{pd_:.3f} | {nav:.3f} | {headroom_pct(nav, pd_):.0f} %")
            lines.append(f"| `{name}` | {sweep} | {' | '.join(cells)} |")
    lines.append("")
    return "\n".join(lines)


def _calibration(ctx: ReportContext) -> str | None:
    result = ctx.json("pd_baseline.json")
    return None if result is None else pd_calibration_section(result)


def _sensing(ctx: ReportContext) -> str | None:
    """The default preset's file first (under its preset's name), then one per ``--sensors`` run."""
    default = ctx.json("pd_baseline.json")
    presets = {stem.removeprefix("pd_baseline_"): r for stem, r in ctx.jsons("pd_baseline_*.json").items()}
    if default is None or not presets:
        return None
    return sensing_presets_section({default.get("sensors", "rtk"): default} | presets)


CALIBRATION = Section("pd_calibration", "PD baseline on the paper's evaluation sweeps", ("results/pd_baseline.json",),
                      _calibration)
SENSING = Section("sensing_presets", "PD and navigation error under each sensing preset",
                  ("results/pd_baseline.json", "results/pd_baseline_*.json"), _sensing)
