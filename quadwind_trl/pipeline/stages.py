"""A stage of the pipeline, what it asks a scheduler for, and the per-stage time record."""
from __future__ import annotations

import json
import math
import os
import socket
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

from ..manifest import write_json


@dataclass(frozen=True)
class StageResources:
    """What one stage asks a scheduler for (``--executor ray``: the Ray task's ``num_cpus``,
    ``num_gpus`` and ``memory``). Ray reserves these, it does not enforce them: a stage that
    uses more slows its neighbours on the node, or is killed by the node's memory monitor.

    The defaults fit every stage as the pipeline runs them: each recipe is one single-threaded
    process on the CPU (``--threads 1``). ``pipeline_times.json`` records each stage's peak
    resident memory under Ray, the figure to size ``memory_gib`` from on a cluster.
    """

    cpus: float = 1.0  # cores
    gpus: float = 0.0  # devices; the recipes run on the CPU unless given --device
    memory_gib: float = 2.0  # GiB of the node's RAM, reserved

    def __post_init__(self) -> None:
        for name in ("cpus", "gpus", "memory_gib"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"StageResources.{name}={value!r}: allowed range: a finite number >= 0")
        if self.cpus == 0 and self.gpus == 0:
            raise ValueError("StageResources: cpus=0 and gpus=0; a stage needs at least some of one")


@dataclass(frozen=True)
class Stage:
    name: str
    args: tuple[str, ...]  # a recipe and its arguments; () for a stage that is only ``after``
    output: Path  # the stage is done when this exists
    after: Callable[[], None] | None = None  # run in the driving process once the recipe has finished
    # the stages whose outputs this one reads; None: every stage listed before it. Every recipe
    # runs single-threaded, so two stages with nothing between them can share two cores
    needs: tuple[str, ...] | None = None
    resources: StageResources = field(default_factory=StageResources)
    rerun: bool = False  # run even when its output exists: a summary of what the other stages left


def stage_needs(stage: Stage, plan: Sequence[Stage]) -> tuple[str, ...]:
    """The stages ``stage`` waits for: its own list, or every stage before it in the plan."""
    if stage.needs is not None:
        return stage.needs
    return tuple(s.name for s in plan[:list(plan).index(stage)])


def is_forced(stage: Stage, force: Sequence[str]) -> bool:
    return "all" in force or stage.name in force


def is_done(stage: Stage, force: Sequence[str]) -> bool:
    """Skip ``stage``: its output exists, and it is neither forced nor a stage that always reruns."""
    return stage.output.exists() and not is_forced(stage, force) and not stage.rerun


def settle(stage: Stage, force: Sequence[str], finished: set[str], finish: Callable[[Stage], None]) -> bool:
    """Settle in this process a stage that needs no recipe run: one already done is skipped, one
    that is only ``after`` is finished by ``finish``; False where the recipe has to run."""
    if is_done(stage, force):
        print(f"[{stage.name}] done already ({stage.output}); skipping", flush=True)
        finished.add(stage.name)
        return True
    if not stage.args:
        finish(stage)
        return True
    return False


def check_all_ran(failed: Sequence[str], waiting: Sequence[Stage]) -> None:
    """End a run whose stages ``failed`` (exit 1), or that left stages ``waiting`` for ones never run."""
    if failed:
        raise SystemExit(f"error: stage{'s' if len(failed) > 1 else ''} {', '.join(failed)} failed; "
                         f"{len(waiting)} stage{'s' if len(waiting) != 1 else ''} did not start")
    if waiting:  # nothing failed, yet these could never start: they need a stage that is not in the plan
        raise RuntimeError(f"stages {[s.name for s in waiting]} wait for stages that never run")


@dataclass(frozen=True)
class Chain:
    """The plan's longest chain of dependent stages by recorded wall time: on enough nodes, a
    reproduction takes about this long whatever else runs beside it."""

    seconds: float  # the chain's recorded wall time, stage by stage
    stages: tuple[tuple[str, float | None], ...]  # (name, recorded seconds) from first to last
    untimed: tuple[str, ...]  # stages of the plan with no recorded time, counted as 0 s


def longest_chain(plan: Sequence[Stage], times: dict[str, dict]) -> Chain:
    """The longest chain of ``plan`` (a stage after every stage it needs) under the wall times of
    ``times`` (``pipeline_times.json``'s entries). A stage with no record counts as 0 s and is
    listed in ``untimed``: the chain is then a lower bound."""
    finish: dict[str, float] = {}
    previous: dict[str, str | None] = {}
    untimed = []
    for stage in plan:  # a plan lists every stage after the stages it needs
        seconds = times.get(stage.name, {}).get("wall_time_s")
        if seconds is None:
            untimed.append(stage.name)
        # on a tie the later stage, so that an untimed stage (0 s) stays on the chain it ends
        before = max(reversed(stage_needs(stage, plan)), key=finish.__getitem__, default=None)
        finish[stage.name] = (seconds or 0.0) + (finish[before] if before else 0.0)
        previous[stage.name] = before
    name = max(finish, key=finish.__getitem__, default=None)
    seconds = finish[name] if name else 0.0
    chain = []
    while name:
        chain.append((name, times.get(name, {}).get("wall_time_s")))
        name = previous[name]
    return Chain(seconds, tuple(reversed(chain)), tuple(untimed))


def record_time(path: Path, stage: str, seconds: float, commit: str | None, *, node: str | None = None,
                load: float | None = None, **extra) -> None:
    """Add a finished stage's wall time, with the machine it ran on (``node``: this one by
    default), that machine's 1-minute load as it finished (``load``: this one's by default) and
    the commit it ran at, to ``path``: the per-stage record that a reproduction spanning several
    sessions adds up. ``extra`` entries (an executor's own, e.g. the Ray node id) go in as given."""
    record = json.loads(path.read_text()) if path.exists() else {}
    record[stage] = {"wall_time_s": round(seconds, 1), "finished": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
                     "git_commit": commit, "node": node or socket.gethostname(),
                     "load_average_1min": round(os.getloadavg()[0] if load is None else load, 2), **extra}
    write_json(path, record)
