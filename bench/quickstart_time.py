"""The README's quickstart as a new user runs it, at one or more commits: a fresh clone, empty
caches (``XDG_CACHE_HOME``: the library's, pip's and Matplotlib's; ``TORCHINDUCTOR_CACHE_DIR``),
then ``bash scripts/quickstart.sh`` as written. The commits take turns, so that before and after
meet the same machine load.

    python bench/quickstart_time.py ee2b509 HEAD              # one run each, in this order
    python bench/quickstart_time.py ee2b509 HEAD --rounds 2   # before, after, before, after

One parseable line per run::

    quickstart commit=... wall_s=... install_s=... pipeline_s=... first_flight_s=... cpu_s=...
        load_start=... load_end=... first_flight="+39.8 % ... 16/16 ..."

``install_s`` runs until the quickstart's first line after its install; ``pipeline_s`` and
``first_flight_s`` are what ``recipes/reproduce.py`` and ``recipes/first_flight.py`` report for
their stages and their flights; ``first_flight`` is the paired result the README prints.
``cpu_s`` is the CPU time of the whole process tree, the stage server's processes included (they
are not the shell's children, so ``time`` misses them), from a cpuacct cgroup of its own where
this user may make one (root, cgroup v1), else ``nan``.
"""
from __future__ import annotations

import argparse
import math
import os
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

from machine import load_1min, machine_line

ROOT = Path(__file__).resolve().parent.parent
CPUACCT = Path("/sys/fs/cgroup/cpuacct")
# the line scripts/quickstart.sh prints once its install is done
INSTALLED = "flies against PD beside the pipeline"


def _cgroup() -> Path | None:
    """A cpuacct group of this process's own, or None where none can be made."""
    group = CPUACCT / f"quickstart-bench-{os.getpid()}"
    try:
        group.mkdir()
    except OSError:
        return None
    return group


def _remove(group: Path, timeout_s: float = 30.0) -> None:
    """Remove ``group`` once its last process has gone (the stage server exits just after the
    quickstart)."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            group.rmdir()
            return
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def run_once(commit: str, work: Path) -> dict:
    """One quickstart from a fresh clone of ``commit`` under ``work``; its figures."""
    clone, cache = work / "clone", work / "cache"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    subprocess.run(["git", "checkout", "-q", commit], cwd=clone, check=True)
    # a new user's environment: no bytecode or buffering settings of this shell's
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONDONTWRITEBYTECODE", "PYTHONUNBUFFERED", "PYTHONPATH")}
    env.update(XDG_CACHE_HOME=str(cache), TORCHINDUCTOR_CACHE_DIR=str(cache / "inductor"))
    group = _cgroup()
    joined = (lambda: (group / "tasks").write_text(str(os.getpid()))) if group else None
    load_start, t0 = load_1min(), time.perf_counter()
    proc = subprocess.Popen(["bash", "scripts/quickstart.sh"], cwd=clone, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, preexec_fn=joined)
    install_s, lines = math.nan, []
    for line in proc.stdout:
        lines.append(line)
        if INSTALLED in line and math.isnan(install_s):
            install_s = time.perf_counter() - t0
    wall_s = time.perf_counter() - t0
    if proc.wait() != 0:
        raise RuntimeError(f"quickstart at {commit} failed:\n{''.join(lines[-40:])}")
    cpu_s = math.nan
    if group is not None:
        cpu_s = int((group / "cpuacct.usage").read_text()) / 1e9
        _remove(group)
    text = "".join(lines)
    paired = re.search(r"wind-aware RL vs PD on the same episodes: (.*?); height", text)
    return dict(commit=commit, wall_s=wall_s, install_s=install_s,
                pipeline_s=float(re.search(r"stages finished in (\d+) s", text).group(1)),
                first_flight_s=float(re.search(r"flown in (\d+) s", text).group(1)), cpu_s=cpu_s,
                load_start=load_start, load_end=load_1min(), first_flight=paired.group(1) if paired else "")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("commits", nargs="+", help="commits (or refs) of this repository, run in turn")
    parser.add_argument("--rounds", type=int, default=1, help="times each commit runs (default 1)")
    args = parser.parse_args()
    if args.rounds < 1:
        parser.error(f"--rounds={args.rounds}: run at least 1 round")
    commits = [subprocess.run(["git", "rev-parse", "--short", c], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip() for c in args.commits]
    # every recipe of the quickstart runs on one thread; two pipeline stages and the first flight at once
    print(machine_line(threads=1, workers=3), flush=True)
    for _ in range(args.rounds):
        for commit in commits:
            work = Path(tempfile.mkdtemp(prefix="quickstart-bench-"))
            try:
                r = run_once(commit, work)
            finally:
                shutil.rmtree(work, ignore_errors=True)
            print(f"quickstart commit={r['commit']} wall_s={r['wall_s']:.1f} install_s={r['install_s']:.1f} "
                  f"pipeline_s={r['pipeline_s']:.0f} first_flight_s={r['first_flight_s']:.0f} cpu_s={r['cpu_s']:.1f} "
                  f"load_start={r['load_start']:.2f} load_end={r['load_end']:.2f} first_flight=\"{r['first_flight']}\"",
                  flush=True)


if __name__ == "__main__":
    main()
