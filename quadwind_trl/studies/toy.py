"""The ``--quick`` run's page (``recipes/reproduce.py --quick``): says first that it is a toy, and
shows only what it flew, with no paper columns."""
from __future__ import annotations

from pathlib import Path

from .section import ReportContext, Section
from .tables import ci


TOY_PREAMBLE = """# Toy run: not the paper's results

`python recipes/reproduce.py --quick` ran every stage at toy scale (a few wind cases, flights of
seconds, 1,024 PPO decisions), to show the pipeline works end to end on your machine. Its numbers
say nothing about the method: the estimators and policies are barely trained, and each table
counts only the episodes flown here. The paper-scale results are in `docs/results.md` of the
repository (`python recipes/reproduce.py --full` remakes them, in hours).
"""


def toy_tracking_section(pd: dict | None, ablations: dict[str, dict], figures: list[Path]) -> str:
    """The toy run's tracking numbers, with the episode counts it flew and no paper columns."""
    lines = ["## Tracking (toy scale)", "",
             "RMSE reduction = 1 - mean RL / mean PD (positive: RL tracks better), paired bootstrap 95 % interval.", "",
             "| sweep | episodes | PD xy RMSE (m) | wind-aware RL xy RMSE (m) | xy RMSE reduction (95 % CI) | wins |",
             "|---|---|---|---|---|---|"]
    for name, result in ablations.items():
        block = result["rmse_xy"]
        d, a = block["distribution"], block["aware"]
        lines.append(f"| {name} | {a['n']} | {d['pd']['mean']:.3f} | {d['aware']['mean']:.3f} | "
                     f"{a['improvement']:.1f} % ({ci(a)}) | {a['wins']}/{a['n']} |")
    if pd is not None and not ablations:
        for name, sweep in pd["sweeps"].items():
            a = sweep["tables"]["rmse_xy"]["all"]
            lines.append(f"| {name} | {a.get('n', '-')} | {a['mean']:.3f} | - | - | - |")
    lines.append("")
    lines += [f"- [{fig.stem}](figures/{fig.name})" for fig in figures]
    return "\n".join(lines + [""])


def _render(ctx: ReportContext) -> str:
    return toy_tracking_section(ctx.json("pd_baseline.json"), ctx.ablations,
                                sorted((ctx.results.parent / "figures").glob("*.png")))


SECTION = Section("toy_tracking", "Tracking (toy scale)", ("results/pd_baseline.json", "results/ablation_*.json"), _render)
