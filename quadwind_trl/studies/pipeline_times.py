"""The wall time of each stage of ``recipes/reproduce.py --full`` on the results page
(``results/pipeline_times.json``, recorded by the pipeline as each stage finished)."""
from __future__ import annotations

from .section import Section
from .tables import wall_time


def pipeline_section(times: dict[str, dict]) -> str:
    """The wall time of each stage of ``recipes/reproduce.py --full`` (``results/pipeline_times.json``)."""
    lines = ["## Pipeline wall time on this machine", "",
             "Per stage of `python recipes/reproduce.py --full`, as each finished (stages ran over several sessions, some",
             "beside another job on the other core: the 1-minute load average at the end is given).", "",
             "| stage | wall time | finished | commit | load | note |", "|---|---|---|---|---|---|"]
    for stage, t in times.items():
        load = t.get("load_average_1min")
        lines.append(f"| {stage} | {wall_time(t['wall_time_s'])} | {t['finished']} | `{t['git_commit']}` | "
                     f"{'-' if load is None else load} | {t.get('note', '')} |")
    total = sum(t["wall_time_s"] for t in times.values())
    lines += [f"| sum of the recorded stages (more than the elapsed time when two ran at once) | {wall_time(total)} | | | | |", ""]
    return "\n".join(lines)


SECTION = Section.of_results("pipeline_times", "Pipeline wall time on this machine", "pipeline_times.json",
                             pipeline_section)
