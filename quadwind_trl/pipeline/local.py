"""The pipeline's own executor: each stage a process of this machine, up to ``jobs`` at once.

Every stage's recipe starts by importing torch, TensorDict, TorchRL, SciPy and the library: about
3.5 s of CPU per process, a third of a toy stage's work (docs/benchmarks.md, "Newcomer commands"). So the stages are not started as new
interpreters but forked from one server process (multiprocessing's ``forkserver``) that has
imported :data:`PRELOADED` once; each stage is still its own process, with its own output, exit
status, working folder and environment, and runs its recipe as ``python recipe.py ARGS`` would.
"""
from __future__ import annotations

import atexit
import multiprocessing
import os
import runpy
import sys
import threading
import time
import traceback
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Callable, Sequence

from ..manifest import git_commit
from .stages import Stage, check_all_ran, is_done, record_time, settle, stage_needs

#: What the stage server imports before it starts any stage: what the recipes import at their top
#: (the simulator, the RL env, the estimator, the evaluation with SciPy and Matplotlib). Imports
#: only: nothing here runs a tensor operation, so a forked stage starts as a new process would
PRELOADED = ("torch", "tensordict", "torchrl", "quadwind_trl.rl.envs", "quadwind_trl.estimator", "quadwind_trl.evaluation")


def _stage_context() -> multiprocessing.context.ForkServerContext:
    """The forkserver context the stages start from, its server importing :data:`PRELOADED`
    (a server already running in this process keeps what it imported)."""
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(list(PRELOADED))
    return context


def _run_recipe(cmd: list[str], cwd: str, env: dict[str, str], output: Connection) -> None:
    """In the stage's process: ``python cmd[0] cmd[1:]`` in ``cwd`` with ``env``, its stdout and
    stderr (and those of any process it starts) on ``output``; the recipe's exit status is the
    process's."""
    for fd in (1, 2):
        os.dup2(output.fileno(), fd)
    output.close()
    # line-buffered as PYTHONUNBUFFERED makes a new interpreter's streams: lines as they come
    sys.stdout = open(1, "w", buffering=1, encoding="utf-8", errors="backslashreplace", closefd=False)
    sys.stderr = open(2, "w", buffering=1, encoding="utf-8", errors="backslashreplace", closefd=False)
    os.chdir(cwd)
    os.environ.clear()
    os.environ.update(env)
    script = os.path.abspath(cmd[0])
    sys.argv = [script, *cmd[1:]]
    sys.path.insert(0, os.path.dirname(script))  # as the interpreter does for a script it runs
    status = 0
    try:
        runpy.run_path(script, run_name="__main__")
    except SystemExit as exit_:
        status = exit_.code
    except BaseException:
        traceback.print_exc()
        status = 1
    finally:
        # a forked process ends without the interpreter's shutdown, which runs the recipe's exit
        # handlers (the output locks it holds are released by them)
        atexit._run_exitfuncs()
        sys.stdout.flush()
        sys.stderr.flush()
    sys.exit(status)


class _Running:
    """One stage's recipe, running as its own process; its output lines, prefixed with the
    stage's name, reach this process's stdout whole (stages that run at once interleave by line)."""

    def __init__(self, stage: Stage, cmd: list[str], cwd: Path, context: multiprocessing.context.ForkServerContext):
        self.stage, self.t0, self.commit = stage, time.perf_counter(), git_commit()  # before it writes shipped files
        print(f"[{stage.name}] {' '.join(cmd)}", flush=True)
        reader, writer = context.Pipe(duplex=False)
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}  # for the processes a recipe starts: lines as they come
        self.proc = context.Process(target=_run_recipe, args=(cmd, str(cwd), env, writer), name=stage.name)
        self.proc.start()
        writer.close()  # the stage holds the only writer: its exit ends the relay
        self.stream = os.fdopen(os.dup(reader.fileno()), "r", encoding="utf-8", errors="backslashreplace")
        reader.close()
        self.relay = threading.Thread(target=self._relay, daemon=True)
        self.relay.start()

    def _relay(self) -> None:
        with self.stream:
            for line in self.stream:
                print(f"[{self.stage.name}] {line}", end="", flush=True)

    @property
    def returncode(self) -> int | None:
        """The recipe's exit status, None while it runs."""
        return self.proc.exitcode


def run_stages_locally(selected: Sequence[Stage], plan: Sequence[Stage], force: Sequence[str], jobs: int, times: Path,
                       command: Callable[[Stage], list[str]], cwd: Path) -> None:
    """Run ``selected`` (in ``plan``'s order), up to ``jobs`` at once, each once the stages it
    needs have finished or are not selected; a stage whose output exists is skipped unless forced.
    ``command`` gives a stage's recipe and arguments, run in ``cwd`` (a process forked from the
    stage server, :data:`PRELOADED` imported). On a failure no new stage starts, the running ones
    finish, and the command exits 1. As with any multiprocessing program, a script that calls this
    runs it under ``if __name__ == "__main__":`` (each stage's process imports the script first)."""
    if jobs < 1:
        raise ValueError(f"jobs={jobs}: run at least 1 stage at a time")
    names = {s.name for s in selected}
    waiting, running, finished, failed = list(selected), [], set(), []
    context = _stage_context()

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
                running.append(_Running(stage, command(stage), cwd, context))

    while True:
        start_ready()
        if not running:
            break
        time.sleep(0.2)
        for job in [j for j in running if j.returncode is not None]:
            running.remove(job)
            job.relay.join()
            if job.returncode == 0:
                finish(job.stage, job.t0, job.commit)
            else:
                print(f"[{job.stage.name}] failed (exit status {job.returncode})", flush=True)
                failed.append(job.stage.name)
    check_all_ran(failed, waiting)
