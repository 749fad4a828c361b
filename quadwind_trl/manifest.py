"""Provenance for every artifact the repo ships: command, config, commit, metrics,
written atomically."""
from __future__ import annotations

import json
import os
import platform
import re
import shlex
import subprocess
from functools import cache
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


#: environment variables that change which kernels ATen, MKL or oneDNN run (and so the last bits)
KERNEL_ENV = ("ATEN_CPU_CAPABILITY", "MKL_ENABLE_INSTRUCTIONS", "MKL_CBWR", "ONEDNN_MAX_CPU_ISA", "OMP_NUM_THREADS")
#: the parts of :func:`platform_info` that decide bitwise replay (docs/simulator.md, "Exact replay")
PLATFORM_KEY = ("machine", "cpu", "aten_cpu_capability", "blas", "torch", "kernel_env", "torch_threads")


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


@cache
def _blas() -> str:
    """The BLAS torch was built with and its version, from ``torch.__config__.show()``."""
    import torch

    shown = torch.__config__.show()
    name = re.search(r"BLAS_INFO=([^,\s]+)", shown)
    version = re.search(r"Math Kernel Library Version ([^\s]+)", shown) or re.search(r"OpenBLAS ([^\s]+)", shown)
    return " ".join(filter(None, (name and name.group(1), version and version.group(1)))) or "unknown"


def platform_info() -> dict:
    """What a bitwise replay depends on besides the code and the inputs: the processor, the kernel
    path ATen dispatches to (``torch.backends.cpu.get_cpu_capability()``, which
    ``ATEN_CPU_CAPABILITY`` can lower), the BLAS and its version, torch, the environment variables
    that change kernel choice, and the thread count. Every manifest and results file records it;
    :func:`same_platform` compares two."""
    import torch

    return {
        "machine": platform.machine(),
        "cpu": _cpu_model(),
        "aten_cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "blas": _blas(),
        "torch": torch.__version__,
        "kernel_env": {k: os.environ[k] for k in KERNEL_ENV if k in os.environ},
        "torch_threads": torch.get_num_threads(),
        "vector_isa": _vector_isa(),
    }


@cache  # the processor does not change within a process: /proc/cpuinfo is read once
def _vector_isa() -> str | None:
    """The widest vector instruction set the processor itself has ("AVX512", "AVX2" or "DEFAULT"),
    whatever ``ATEN_CPU_CAPABILITY`` lowers ATen to; None where /proc/cpuinfo is not readable."""
    try:
        flags = set(next(line for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("flags")).split())
    except (OSError, StopIteration):
        return None
    return "AVX512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "DEFAULT"


def same_vector_isa(a: dict | None, b: dict | None) -> bool:
    """Whether two :func:`platform_info` records come from processors with the same vector
    instruction set. Records made before ``vector_isa`` was recorded are read from the ATen
    capability they ran, where no environment variable had lowered it."""
    def isa(p: dict | None) -> str | None:
        if p is None:
            return None
        if p.get("vector_isa") is not None:
            return p["vector_isa"]
        return None if "ATEN_CPU_CAPABILITY" in (p.get("kernel_env") or {}) else p.get("aten_cpu_capability")

    return isa(a) is not None and isa(a) == isa(b)


def same_processor(a: dict | None, b: dict | None) -> bool:
    """Whether two :func:`platform_info` records come from the same processor model (its name and
    its vector instruction set, :func:`same_vector_isa`), whatever the torch build, kernel path
    or environment."""
    return same_vector_isa(a, b) and a.get("cpu") == b.get("cpu")


def same_platform(a: dict | None, b: dict | None) -> bool:
    """Whether two :func:`platform_info` records name the same platform (so bitwise replay is the
    promise between them); a record without one (made before platforms were recorded) never is."""
    return a is not None and b is not None and all(a.get(k) == b.get(k) for k in PLATFORM_KEY)


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


def checkout_root(path: str | os.PathLike) -> Path | None:
    """The nearest directory at or above ``path`` that is a checkout of this project (it holds
    ``pyproject.toml`` and ``quadwind_trl/__init__.py``): this one (:data:`ROOT`) or another
    worktree or clone of the same repository; None when there is none."""
    path = Path(path)
    for folder in (path, *path.parents):
        if (folder / "pyproject.toml").is_file() and (folder / "quadwind_trl" / "__init__.py").is_file():
            return folder
    return None


def repo_relative(path: str | os.PathLike) -> str:
    """``path`` relative to the repository (what a manifest records: the machine's own directories
    mean nothing on another): relative to this checkout's root when it lies inside it, else to
    the checkout of this project it lies in (a run in another worktree of the same repository,
    with the package imported from this one, names that worktree's files); a path in no
    checkout, or an already relative one, is unchanged."""
    p = Path(path)
    if not p.is_absolute():
        return str(p)
    resolved = p.resolve()
    for root in (ROOT, checkout_root(resolved)):
        if root is not None and resolved.is_relative_to(root):
            return str(resolved.relative_to(root))
    return str(p)


def command_line(argv: list[str]) -> str:
    """The command a manifest records: ``python`` and ``argv`` with repository paths relative
    (``PATH`` and ``--option=PATH`` alike)."""

    def relative(arg: str) -> str:
        if os.path.isabs(arg):
            return repo_relative(arg)
        option, eq, value = arg.partition("=")
        return f"{option}={repo_relative(value)}" if eq and option.startswith("-") and os.path.isabs(value) else arg

    return shlex.join(["python"] + [relative(a) for a in argv])


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
