"""The pipeline's stages as Ray tasks (``recipes/reproduce.py --executor ray [--address ...]``).

Each stage whose recipe runs is one Ray task asking for its :class:`~quadwind_trl.pipeline.StageResources`
(CPUs, GPUs, memory); it is handed to Ray once the stages it reads have finished, so Ray places it
on any node with room. The task runs the recipe as a child process of the Ray worker, with the
worker's Python, in the repository folder the driver names, and relays its output lines (prefixed
with the stage's name) to the driver. Every node therefore needs the repository at the same path
and its outputs on a file system all nodes share (the stages read each other's outputs); the
recipes' one-writer locks (:mod:`quadwind_trl.outputs`) are ``flock`` locks on that file system.

A worker that dies (the node lost, the worker killed) takes its recipe with it (the child gets
SIGKILL when the worker goes), and Ray runs the task again, up to ``max_retries`` times; so does a
recipe killed by a signal (the node's memory monitor, an operator). The retry starts the recipe
over with the same arguments: the long stages pass ``--resume`` and go on from their last
checkpoint, the others start again and replace their partial output. A recipe that exits with an
error is not retried: it would fail the same way.

This module imports Ray only when :func:`connect` (:mod:`quadwind_trl.ray_cluster`) or
:func:`run_stages_on_ray` is called; the local executor never imports it.
"""
from __future__ import annotations

import ctypes
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, Sequence

from ..manifest import KERNEL_ENV, git_commit
from .. import ray_cluster
from ..ray_cluster import RayUnavailable, parse_address  # noqa: F401  (the executor's errors and address format)
from .stages import Stage, check_all_ran, record_time, settle, stage_needs

#: times Ray reruns a stage whose worker died or whose recipe was killed
DEFAULT_MAX_RETRIES = 3
#: seconds between the driver's checks for finished stages
POLL_S = 1.0


class StageKilled(RuntimeError):
    """A stage's recipe was killed by a signal; Ray retries the task."""


# what a missing Ray's error names: the option that needs it, and what to do instead
_NEEDS_RAY = {"option": "--executor ray", "alternative": "leave out --executor ray and --address to run the stages as local processes"}


def _import_ray():
    return ray_cluster.import_ray(**_NEEDS_RAY)


def connect(address: str | None, local_cpus: int) -> str:
    """Join the Ray cluster at ``address`` (``--address``: "auto" or the head node's HOST:PORT), or
    with None start a local Ray instance of ``local_cpus`` CPUs (:func:`quadwind_trl.ray_cluster.connect`)."""
    return ray_cluster.connect(address, local_cpus, **_NEEDS_RAY)


def _die_with_parent() -> None:
    """In the recipe's process, before it starts: receive SIGKILL when the Ray worker that started
    it dies, so a retry never finds the previous attempt still writing (Linux; elsewhere a
    killed worker's recipe runs on and the retry meets its output lock)."""
    if sys.platform.startswith("linux"):
        PR_SET_PDEATHSIG = 1
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


def run_stage(name: str, cmd: Sequence[str], cwd: str, kernel_env: dict[str, str | None]) -> dict:
    """One stage in a Ray worker: run the recipe ``cmd`` (a script and its arguments) with this
    worker's Python in ``cwd``, relay its output, and say how it ended and where it ran.

    ``kernel_env`` holds the driver's values of the variables that choose the CPU kernels
    (:data:`~quadwind_trl.manifest.KERNEL_ENV`; None: unset) and replaces the worker's: Ray sets
    ``OMP_NUM_THREADS`` to a task's CPUs, and a manifest that recorded it would name another
    platform than the local executor's run, whose re-flights are then no longer checked bit for bit."""
    import ray

    t0 = time.perf_counter()
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONPATH": os.pathsep.join(filter(None, [cwd, os.environ.get("PYTHONPATH")]))}
    for key, value in kernel_env.items():
        if value is None:
            env.pop(key, None)
        else:
            env[key] = value
    proc = subprocess.Popen([sys.executable, *cmd], cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            bufsize=1, env=env, preexec_fn=_die_with_parent)
    for line in proc.stdout:
        print(f"[{name}] {line}", end="", flush=True)
    _, status, usage = os.wait4(proc.pid, 0)  # this child's own peak memory (a worker runs many stages)
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode < 0:
        raise StageKilled(f"stage {name}: its recipe was killed by signal {-proc.returncode}")
    return {"returncode": proc.returncode, "seconds": time.perf_counter() - t0, "node": socket.gethostname(),
            "ray_node": ray.get_runtime_context().get_node_id()[:12], "load": os.getloadavg()[0],
            "peak_rss_mib": round(usage.ru_maxrss / 1024 if sys.platform.startswith("linux") else usage.ru_maxrss / 2**20, 1)}


def check_fits(stages: Sequence[Stage], nodes: Sequence[dict]) -> None:
    """Refuse a stage that no node of the cluster could ever run (Ray would hold it forever):
    ``nodes`` are the nodes' total resources as Ray names them (``CPU``, ``GPU``, ``memory`` in bytes)."""
    for stage in stages:
        if not stage.args:
            continue
        r = stage.resources
        asked = {"CPU": r.cpus, "GPU": r.gpus, "memory": r.memory_gib * 2**30}
        if not any(all(node.get(key, 0) >= value for key, value in asked.items() if value) for node in nodes):
            largest = {key: max((node.get(key, 0) for node in nodes), default=0) for key in asked}
            raise ValueError(f"stage {stage.name} asks for {r} and no node of the cluster has that much (the largest: "
                             f"{largest['CPU']:g} CPUs, {largest['GPU']:g} GPUs, {largest['memory'] / 2**30:.1f} GiB of "
                             "memory for tasks); add a node, or lower the stage's StageResources")


def run_stages_on_ray(selected: Sequence[Stage], plan: Sequence[Stage], force: Sequence[str], times: Path,
                      command: Callable[[Stage], list[str]], cwd: Path, *, max_retries: int = DEFAULT_MAX_RETRIES) -> None:
    """Run ``selected`` (in ``plan``'s order) as Ray tasks on the cluster :func:`connect` joined,
    each handed to Ray once the stages it needs have finished or are not selected; a stage whose
    output exists is skipped unless forced (``force``), and ``Stage.after`` runs here. ``command``
    gives a stage's recipe and arguments, run in ``cwd``. Each finished stage's wall time, node,
    load and peak memory go to ``times``. On a failure nothing more is handed to Ray, the stages it
    holds finish, and the command exits 1 (as the local executor does)."""
    if max_retries < 0:
        raise ValueError(f"max_retries={max_retries}: allowed range: >= 0")
    ray = _import_ray()
    check_fits(selected, [n["Resources"] for n in ray.nodes() if n.get("Alive")])
    task = ray.remote(run_stage)
    kernel_env = {key: os.environ.get(key) for key in KERNEL_ENV}
    names = {s.name for s in selected}
    waiting, running, finished, failed = list(selected), {}, set(), []

    def finish(stage: Stage, seconds: float, commit: str | None, **where) -> None:
        if stage.after is not None:
            stage.after()
        print(f"[{stage.name}] finished in {seconds:.0f} s", flush=True)
        record_time(times, stage.name, seconds, commit, **where)
        finished.add(stage.name)

    def hand_over_ready() -> None:
        """Skip, finish or hand to Ray every stage that can go now (in plan order), until none can."""
        while not failed:
            stage = next((s for s in waiting if all(n in finished or n not in names for n in stage_needs(s, plan))), None)
            if stage is None:
                return
            waiting.remove(stage)
            if not settle(stage, force, finished, lambda s: finish(s, 0.0, git_commit())):
                cmd = command(stage)
                print(f"[{stage.name}] {' '.join(cmd)}", flush=True)
                r = stage.resources
                options = {"name": stage.name, "num_cpus": r.cpus, "num_gpus": r.gpus, "memory": int(r.memory_gib * 2**30),
                           "max_retries": max_retries, "retry_exceptions": [StageKilled]}
                ref = task.options(**options).remote(stage.name, cmd, str(cwd), kernel_env)
                running[ref] = (stage, git_commit())  # the commit before it writes shipped files

    while True:
        hand_over_ready()
        if not running:
            break
        done, _ = ray.wait(list(running), num_returns=1, timeout=POLL_S)
        for ref in done:
            stage, commit = running.pop(ref)
            try:
                result = ray.get(ref)
            except ray.exceptions.RayError as err:  # e.g. its worker died more than max_retries times
                print(f"[{stage.name}] failed: {err}", flush=True)
                failed.append(stage.name)
                continue
            if result["returncode"] != 0:
                print(f"[{stage.name}] failed (exit status {result['returncode']})", flush=True)
                failed.append(stage.name)
                continue
            finish(stage, result["seconds"], commit, node=result["node"], load=result["load"], ray_node=result["ray_node"],
                   peak_rss_mib=result["peak_rss_mib"])
    check_all_ran(failed, waiting)
