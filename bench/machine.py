"""What every benchmark states beside its figures: threads, workers, machine load, date, versions.

On this project's 2-core machines a second busy process changes a torch job's speed several
times over, so a figure without the load it was taken under cannot be compared with another.
``machine_line`` is printed once at the start of each benchmark; ``load_1min`` is read again
beside each figure.
"""
from __future__ import annotations

import datetime
import json
import os
import platform
import subprocess
import sys

import torch


def load_1min() -> float:
    """The 1-minute load average (runnable processes, this one included)."""
    return os.getloadavg()[0]


def machine_line(threads: int, workers: int = 1) -> str:
    """One parseable line: ``machine cores=2 threads=1 workers=1 load_1min=... date=... torch=...``."""
    import torchrl

    return (
        f"machine cores={os.cpu_count()} threads={threads} workers={workers} load_1min={load_1min():.2f} "
        f"date={datetime.datetime.now(datetime.timezone.utc):%Y-%m-%dT%H:%MZ} cpu={platform.machine()} "
        f"torch={torch.__version__} torchrl={torchrl.__version__}"
    )


def in_fresh_process(label: str, script: str, *args: str) -> dict:
    """Run ``script`` with ``args`` in a fresh interpreter (a measurement as a user's process
    makes it: no compiled code or warm caches from an earlier setting), read the JSON object it
    prints last, and print it as one parseable line ``label key=value ...``."""
    proc = subprocess.run([sys.executable, script, *args], capture_output=True, text=True, check=True)
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    print(label + " " + " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in result.items()), flush=True)
    return result
