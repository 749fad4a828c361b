"""The pipeline's own executor: each stage a process of this machine, up to ``jobs`` at once."""
from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Callable, Sequence

from ..manifest import git_commit
from .stages import Stage, check_all_ran, is_done, record_time, settle, stage_needs


class _Running:
    """One stage's recipe, running as its own process; its output lines, prefixed with the
    stage's name, reach this process's stdout whole (stages that run at once interleave by line)."""

    def __init__(self, stage: Stage, cmd: list[str], cwd: Path):
        self.stage, self.t0, self.commit = stage, time.perf_counter(), git_commit()  # before it writes shipped files
        print(f"[{stage.name}] {' '.join(cmd[1:])}", flush=True)
        self.proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1,
                                     env={**os.environ, "PYTHONUNBUFFERED": "1"})  # lines as they come, not at exit
        self.relay = threading.Thread(target=self._relay, daemon=True)
        self.relay.start()

    def _relay(self) -> None:
        for line in self.proc.stdout:
            print(f"[{self.stage.name}] {line}", end="", flush=True)


def run_stages_locally(selected: Sequence[Stage], plan: Sequence[Stage], force: Sequence[str], jobs: int, times: Path,
                       command: Callable[[Stage], list[str]], cwd: Path) -> None:
    """Run ``selected`` (in ``plan``'s order), up to ``jobs`` at once, each once the stages it
    needs have finished or are not selected; a stage whose output exists is skipped unless forced.
    ``command`` gives a stage's recipe and arguments, run with this Python in ``cwd``. On a failure
    no new stage starts, the running ones finish, and the command exits 1."""
    if jobs < 1:
        raise ValueError(f"jobs={jobs}: run at least 1 stage at a time")
    names = {s.name for s in selected}
    waiting, running, finished, failed = list(selected), [], set(), []

    def finish(stage: Stage, t0: float, commit: str | None) -> None:
        if stage.after is not None:
            stage.after()
        seconds = time.perf_counter() - t0
        print(f"[{stage.name}] finished in {seconds:.0f} s", flush=True)
        record_time(times, stage.name, seconds, commit)
        finished.add(stage.name)

    def start_ready() -> None:
        """Skip, finish or start every stage that can go now (in plan order), until none can."""
        while not failed:
            ready = [s for s in waiting if all(n in finished or n not in names for n in stage_needs(s, plan))]
            stage = next((s for s in ready if is_done(s, force)), None) or (ready[0] if ready and len(running) < jobs else None)
            if stage is None:
                return
            waiting.remove(stage)
            if not settle(stage, force, finished, lambda s: finish(s, time.perf_counter(), git_commit())):
                running.append(_Running(stage, [sys.executable, *command(stage)], cwd))

    while True:
        start_ready()
        if not running:
            break
        time.sleep(0.2)
        for job in [j for j in running if j.proc.poll() is not None]:
            running.remove(job)
            job.relay.join()
            if job.proc.returncode == 0:
                finish(job.stage, job.t0, job.commit)
            else:
                print(f"[{job.stage.name}] failed (exit status {job.proc.returncode})", flush=True)
                failed.append(job.stage.name)
    check_all_ran(failed, waiting)
