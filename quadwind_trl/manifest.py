"""Provenance for every artifact the repo ships: command, config, commit, metrics (DESIGN.md,
invariant 6), written atomically."""
from __future__ import annotations

import json
import os
import shlex
import subprocess
from pathlib import Path
from typing import ClassVar


def git_commit() -> str | None:
    """The checked-out commit (with ``-dirty`` if the tree has changes), or None outside git."""
    try:
        root = Path(__file__).resolve().parent.parent
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root, capture_output=True, text=True).stdout.strip()
        return sha + ("-dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return None


def save_atomic(obj, path: str | os.PathLike) -> None:
    """``torch.save`` through a temporary file in the same folder and an atomic rename: a reader
    never sees a half-written checkpoint, even if the writer is killed."""
    import torch

    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def write_json(path: str | os.PathLike, payload: dict) -> None:
    """Write ``payload`` as indented JSON through a temporary file and an atomic rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2, sort_keys=True, default=str) + "\n")
    tmp.replace(path)


ROOT = Path(__file__).resolve().parent.parent
#: the shipped estimator and policy checkpoints (package data; never rewritten by the library)
CHECKPOINT_DIR = Path(__file__).resolve().parent / "checkpoints"


def repo_relative(path: str | os.PathLike) -> str:
    """``path`` relative to the repository root when it lies inside it (what a manifest records:
    the machine's own directories mean nothing on another), else unchanged."""
    p = Path(path)
    try:
        return str(p.resolve().relative_to(ROOT)) if p.is_absolute() else str(p)
    except ValueError:
        return str(p)


def command_line(argv: list[str]) -> str:
    """The command a manifest records: ``python`` and ``argv`` with repository paths relative."""
    return shlex.join(["python"] + [repo_relative(a) if os.path.isabs(a) else a for a in argv])


class CheckpointParts:
    """``state_dict`` / ``load_state_dict`` over a training run's named parts (modules,
    optimisers, schedulers): ``checkpoint_parts`` maps each checkpoint key to the attribute that
    holds the part, so what a checkpoint contains is declared once per trainer."""

    checkpoint_parts: ClassVar[dict[str, str]] = {}

    def state_dict(self) -> dict:
        return {key: getattr(self, attr).state_dict() for key, attr in self.checkpoint_parts.items()}

    def load_state_dict(self, state: dict) -> None:
        for key, attr in self.checkpoint_parts.items():
            getattr(self, attr).load_state_dict(state[key])
