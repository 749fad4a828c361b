"""Where compiled steps are kept between processes, and how a broken entry is rebuilt.

Inductor (torch.compile's compiler) keeps its compiled graphs and C++ libraries in a folder
(``TORCHINDUCTOR_CACHE_DIR``) and trusts what it finds there because it exists: a library
truncated by a compile that was killed while writing it, or by a full disk, fails every later
compile that would load it. Nothing in the cache is the only copy of anything, so a broken entry
is deleted and compiled again, never loaded:

* before the process's first compile, every library in the folder is checked for truncation
  (:func:`truncated_libraries`: an ELF file ends with its section table, so one cut short is seen
  from its header); where one is, nothing in the folder is trusted and it is discarded (moved
  aside first, an atomic rename, so that another process never reads a half-deleted folder).
  Rebuilding the cut libraries alone is not safe: with every file of the folder cut, inductor's
  probes of the vector instructions, rebuilt from their cut sources, failed, and the kernels were
  compiled for another instruction set and flew other bits (docs/benchmarks.md);
* a compile that fails anyway (:func:`discard_broken_entry`) deletes the file its error names, or,
  where it names none, the whole folder, and the caller compiles once more.

A library written in the last :data:`WRITE_GRACE_S` seconds is not judged: another process may be
compiling it right now.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import struct
import sys
import time
import warnings
from pathlib import Path

from ..cache import cache_dir
from ..manifest import platform_info

#: The environment variable that moves the compile cache: a folder, under which each processor
#: and torch version gets a folder of its own (:func:`compile_cache_dir`)
COMPILE_CACHE_ENV = "QUADWIND_TRL_COMPILE_CACHE"
#: What inductor's cache keys leave out and its compiled code depends on (keys of
#: :func:`~quadwind_trl.manifest.platform_info`): it compiles C++ with ``-march=native`` for the
#: vector instruction set ATen's capability (``ATEN_CPU_CAPABILITY``) allows, but keys an entry by
#: the graph, its config and the torch sources only, so a cache shared with another processor (a
#: network home folder) or kernel path would load kernels built for other instructions (a run
#: under ``ATEN_CPU_CAPABILITY=avx2`` that reused an AVX-512 cache crashed)
_COMPILED_CODE_PLATFORM = ("machine", "cpu", "vector_isa", "aten_cpu_capability", "torch")
#: Seconds since its last write before a library is judged: the compiler writes a library at its
#: final path (under inductor's lock for it), so another process's compile in progress shows a
#: short file for the few seconds the linker takes
WRITE_GRACE_S = 60.0
_ELF_MAGIC = b"\x7fELF"


def compile_cache_dir() -> Path:
    """Where compiled steps are kept between processes: ``quadwind_trl/compile`` in the user's
    cache folder (:func:`quadwind_trl.cache.cache_dir`), or the folder the environment
    variable ``QUADWIND_TRL_COMPILE_CACHE`` names, and in it one folder per processor, ATen
    kernel path and torch version (``torch-2.13.0+cpu-avx512-<hash of the processor>``): entries
    made elsewhere are never looked at. The process's first compiled env points inductor's
    cache (``TORCHINDUCTOR_CACHE_DIR``) there, for every ``torch.compile`` of the process."""
    root = Path(os.environ.get(COMPILE_CACHE_ENV) or cache_dir() / "compile").expanduser().absolute()
    platform = platform_info()
    identity = json.dumps({k: platform[k] for k in _COMPILED_CODE_PLATFORM}, sort_keys=True)
    digest = hashlib.sha256(identity.encode()).hexdigest()[:12]
    return root / f"torch-{platform['torch']}-{platform['aten_cpu_capability'].lower()}-{digest}"


def use_compile_cache() -> Path:
    """Point inductor's caches at :func:`compile_cache_dir` (made if missing), discarded first if
    it holds a truncated library (:func:`truncated_libraries`; with a warning)."""
    folder = compile_cache_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OSError(f"compile cache folder {folder} cannot be made ({error.strerror}); set {COMPILE_CACHE_ENV} "
                      "to a writable folder") from error
    truncated = truncated_libraries(folder)
    if truncated:
        _discard_folder(folder)
        warnings.warn(f"the compile cache {folder} held {len(truncated)} truncated librar"
                      f"{'y' if len(truncated) == 1 else 'ies'} (a compile killed while writing, a full disk), "
                      f"e.g. {truncated[0].relative_to(folder)}: it was discarded and is compiled afresh",
                      RuntimeWarning, stacklevel=3)
        folder.mkdir(parents=True, exist_ok=True)
    os.environ["TORCHINDUCTOR_CACHE_DIR"] = str(folder)
    return folder


def _discard_folder(folder: Path) -> None:
    """Delete ``folder``, moved aside first (an atomic rename) so that another process never reads
    it half-deleted: it keeps the files it has open and finds the folder's path empty."""
    stale = folder.with_name(f"{folder.name}.discarded-{os.getpid()}-{time.time_ns()}")
    try:
        folder.rename(stale)
    except FileNotFoundError:  # another process discarded it first
        return
    shutil.rmtree(stale, ignore_errors=True)


def _is_truncated_elf(path: Path) -> bool:
    """Whether the file at ``path`` is not a whole ELF file: shorter than its header says (the
    section header table, which the linker writes last, runs past its end) or no ELF at all."""
    with path.open("rb") as f:
        header = f.read(64)
    if len(header) < 52 or header[:4] != _ELF_MAGIC or header[4] not in (1, 2) or header[5] not in (1, 2):
        return True
    order = "<" if header[5] == 1 else ">"
    if header[4] == 2:  # 64-bit: e_shoff at 0x28, e_shentsize and e_shnum at 0x3A
        if len(header) < 64:
            return True
        (table,), (entry, count) = struct.unpack_from(order + "Q", header, 0x28), struct.unpack_from(order + "HH", header, 0x3A)
    else:  # 32-bit: e_shoff at 0x20, e_shentsize and e_shnum at 0x2E
        (table,), (entry, count) = struct.unpack_from(order + "I", header, 0x20), struct.unpack_from(order + "HH", header, 0x2E)
    return path.stat().st_size < table + entry * count


def truncated_libraries(folder: Path, grace_s: float = WRITE_GRACE_S) -> list[Path]:
    """The compiled libraries (``*.so``) under ``folder`` that are cut short (not a whole ELF
    file), of those not written in the last ``grace_s`` seconds. Only where libraries are ELF
    (Linux); elsewhere none is judged and a broken one is found when it fails to load."""
    if not sys.platform.startswith("linux"):
        return []
    now = time.time()
    return sorted(path for path in folder.rglob("*.so")
                  if path.is_file() and now - path.stat().st_mtime >= grace_s and _is_truncated_elf(path))


def _named_file(error: BaseException, folder: Path) -> Path | None:
    """The file under ``folder`` that ``error`` or an exception it was raised from names (an
    ``ImportError``'s ``path``, an ``OSError``'s ``filename``), if any."""
    seen: set[int] = set()
    while error is not None and id(error) not in seen:
        seen.add(id(error))
        for name in (getattr(error, "path", None), getattr(error, "filename", None)):
            if isinstance(name, str) and Path(name).is_relative_to(folder):
                return Path(name)
        error = getattr(error, "inner_exception", None) or error.__cause__ or error.__context__
    return None


def discard_broken_entry(error: BaseException) -> Path:
    """After a compile failed with ``error``, delete what broke it from the cache: the file under
    :func:`compile_cache_dir` that the error names (another process may be compiling into the
    folder: deleting less spares its work), else the whole folder; and forget what inductor loaded
    in this process. Returns what was deleted."""
    from torch._inductor.utils import clear_caches

    folder = compile_cache_dir()
    named = _named_file(error, folder)
    if named is not None:
        named.unlink(missing_ok=True)
    else:
        _discard_folder(folder)
    clear_caches()
    use_compile_cache()
    return named or folder
