"""One writer per output (docs/architecture.md, "Outputs: one writer, complete means complete").

Every command that writes a dataset, a training run, an estimator checkpoint, a results file or
the report holds :class:`OutputLock` on it for as long as it writes: an exclusive ``flock`` on a
sidecar file beside the output (``DIR/.NAME.lock`` for ``DIR/NAME``), which records the holder's
PID, command and start time for the refusal message. A second writer, in another process or in
this one, is refused at once with :class:`OutputInUse`. The OS drops the lock when its process
dies, so a crash (even ``kill -9``) never leaves a stale lock, only a stale file the next holder
takes over.

:func:`truncate_scalar_logs` keeps a resumed run's CSV logs free of repeated rows: what the
interrupted run logged after its last checkpoint is dropped before the resumed run appends.
"""
from __future__ import annotations

import atexit
import json
import os
import sys
import time
from pathlib import Path
from typing import Callable

from .manifest import command_line, repo_relative

try:
    import fcntl
except ImportError:  # Windows: no flock
    fcntl = None


class OutputInUse(FileExistsError):
    """Another writer holds the output (a :class:`FileExistsError`, so the commands' handlers of
    "the output exists" report it the same way)."""


def lock_path(output: str | os.PathLike) -> Path:
    """The sidecar file locked for ``output``: beside it, so a directory renamed into place (a
    dataset) and a single file are locked the same way."""
    output = Path(output)
    return output.parent / f".{output.name}.lock"


class OutputLock:
    """An exclusive lock on ``output`` (a file or a directory, existing or not), held from
    :meth:`acquire` (or ``with``) to :meth:`release`. ``what`` names the output in the refusal
    message ("dataset", "training run", ...), ``hint`` says what to do instead."""

    def __init__(self, output: str | os.PathLike, what: str = "output",
                 hint: str = "wait for it to finish, or choose another output"):
        self.output = Path(output)
        self.what = what
        self.hint = hint
        self.path = lock_path(self.output.resolve())  # the same file however the output is spelled
        self._fd: int | None = None

    def acquire(self) -> "OutputLock":
        if fcntl is None:
            raise RuntimeError(f"{self.what} {self.output}: output locks need fcntl.flock (Linux, macOS); "
                               f"this platform ({sys.platform}) has none")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        while self._fd is None:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.pread(fd, 4096, 0)
                os.close(fd)
                raise OutputInUse(self._refusal(holder)) from None
            # the previous holder unlinks the file on release: a lock on an unlinked file guards
            # nothing, so take the one now at the path
            if _same_file(fd, self.path):
                self._fd = fd
            else:
                os.close(fd)
        holder = {"pid": os.getpid(), "command": command_line(sys.argv), "since": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
        os.ftruncate(self._fd, 0)
        os.pwrite(self._fd, json.dumps(holder).encode(), 0)
        return self

    def release(self) -> None:
        if self._fd is None:
            return
        if _same_file(self._fd, self.path):  # removed while still locked: no one else holds it
            self.path.unlink()
        os.close(self._fd)
        self._fd = None

    def __enter__(self) -> "OutputLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()

    def _refusal(self, holder: bytes) -> str:
        try:
            h = json.loads(holder)
            own = "this process: " if h["pid"] == os.getpid() else ""
            who = f"PID {h['pid']} ({own}{h['command']}, since {h['since']})"
        except (ValueError, KeyError, TypeError):  # the holder has locked but not yet written its details
            who = "another process"
        return f"{self.what} {repo_relative(self.output)} is being written by {who}: {self.hint}"


def _same_file(fd: int, path: Path) -> bool:
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return False
    own = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (own.st_dev, own.st_ino)


def hold_for_command(*outputs: str | os.PathLike, what: str, hint: str) -> None:
    """Lock ``outputs`` for the rest of a command (a recipe's ``main``), or exit with the refusal
    message (``error: ...``, status 1), as the commands report their other argument errors."""
    for output in outputs:
        try:
            lock = OutputLock(output, what, hint).acquire()
        except OutputInUse as err:
            raise SystemExit(f"error: {err}") from None
        atexit.register(lock.release)


def truncate_scalar_logs(scalars: str | os.PathLike, last_step: Callable[[str], float]) -> None:
    """Drop from every TorchRL CSV log under ``scalars`` (lines ``step,value``) the rows past
    ``last_step(name)`` (``name``: the scalar, e.g. ``"train/reward_mean"``), and a line cut
    short by a kill: a run resumed from a checkpoint then appends from the checkpoint's step,
    repeating and skipping nothing. Each file is rewritten atomically."""
    scalars = Path(scalars)
    for path in sorted(scalars.rglob("*.csv")):
        limit = last_step(path.relative_to(scalars).with_suffix("").as_posix())
        lines = path.read_text().splitlines(keepends=True)
        kept = [line for line in lines if _within(line, limit)]
        if kept != lines:
            tmp = path.with_name(f".{path.name}.tmp")
            tmp.write_text("".join(kept))
            os.replace(tmp, path)


def _within(line: str, limit: float) -> bool:
    """A whole line (a kill can cut the last one short) whose step is at most ``limit``."""
    try:
        return line.endswith("\n") and float(line.split(",", 1)[0]) <= limit
    except ValueError:
        return False
