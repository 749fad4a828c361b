"""Choosing an executor: the command-line options the pipeline recipes share, and :func:`run_plan`."""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Callable, Sequence

from .local import run_stages_locally
from .stages import Stage

EXECUTORS = ("local", "ray")  # the first is the default
DEFAULT_JOBS = 2  # stages at once (--jobs): every recipe runs on one thread, and the target machine has 2 cores


def add_executor_arguments(parser: argparse.ArgumentParser) -> None:
    """``--jobs``, ``--executor`` and ``--address``."""
    parser.add_argument("--jobs", type=int, default=DEFAULT_JOBS,
                        help=f"stages run at once, each a single-threaded process (default {DEFAULT_JOBS}: one per core of a "
                             "2-core machine); a stage starts once the stages it reads have finished. --executor ray "
                             "without --address: the local Ray instance's CPUs")
    parser.add_argument("--executor", default=EXECUTORS[0], choices=EXECUTORS,
                        help="local: each stage a process of this machine, --jobs at a time (default); ray: each stage a "
                             "Ray task asking for its CPUs and memory, on a local Ray instance of --jobs CPUs or on the "
                             "cluster at --address (docs/scaling.md)")
    parser.add_argument("--address", default=None, metavar="auto|HOST:PORT",
                        help="--executor ray: the Ray cluster to run on (auto: the one 'ray start' joined on this machine, "
                             "or RAY_ADDRESS; HOST:PORT: its head node); default: start a local Ray instance")


def check_executor_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    if args.jobs < 1:
        parser.error(f"--jobs={args.jobs}: run at least 1 stage at a time")
    if args.address is not None and args.executor != "ray":
        parser.error(f"--address {args.address}: only with --executor ray")


def run_plan(parser: argparse.ArgumentParser, args: argparse.Namespace, selected: Sequence[Stage], plan: Sequence[Stage],
             times: Path, command: Callable[[Stage], list[str]], cwd: Path) -> None:
    """Run ``selected`` of ``plan`` with the executor ``args`` chose (``--executor``, ``--address``,
    ``--jobs``; ``args.force``: the stages to rerun); a missing Ray or an unreachable cluster ends
    the command through ``parser.error``, naming the option."""
    if args.executor == "local":
        run_stages_locally(selected, plan, args.force, args.jobs, times, command, cwd)
        return
    from .ray_executor import RayUnavailable, connect, run_stages_on_ray

    try:
        print(f"stages run as Ray tasks on {connect(args.address, args.jobs)}", flush=True)
    except RayUnavailable as err:
        parser.error(str(err))
    run_stages_on_ray(selected, plan, args.force, times, command, cwd)
