"""The compile cache: where it lives, and a broken entry deleted and compiled again, never loaded."""
from __future__ import annotations

import _ctypes
import os
import sys
import time
import warnings
from pathlib import Path

import pytest
import torch

from quadwind_trl.config import EnvConfig
from quadwind_trl.envs import QuadWindEnv, compile_cache

# a real shared library to cut short (an extension module of this Python): the check reads ELF headers
_EXTENSION = getattr(_ctypes, "__file__", None) or ""
ELF_LIBRARY = Path(_EXTENSION) if sys.platform.startswith("linux") and _EXTENSION.endswith(".so") else None
linux_only = pytest.mark.skipif(ELF_LIBRARY is None, reason="the truncation check reads ELF libraries (Linux)")


def _aged(path: Path, seconds: float = 2 * compile_cache.WRITE_GRACE_S) -> Path:
    """``path`` last written ``seconds`` ago: a file left by an earlier process."""
    then = time.time() - seconds
    os.utime(path, (then, then))
    return path


def _library(path: Path, size: int | None = None) -> Path:
    """A copy of a real library at ``path``, cut to ``size`` bytes."""
    path.parent.mkdir(parents=True, exist_ok=True)
    data = ELF_LIBRARY.read_bytes()
    path.write_bytes(data if size is None else data[:size])
    return path


def test_the_compile_cache_is_the_users_and_one_folder_per_processor(tmp_path, monkeypatch):
    """The compile cache lives under the library's cache root (the user's cache folder,
    XDG_CACHE_HOME, unless QUADWIND_TRL_CACHE_DIR moves it), or where its own variable says, in a
    folder of the processor, kernel path and torch version: inductor's keys leave the processor
    out, so a cache shared with another one must not be looked at."""
    from quadwind_trl.cache import CACHE_DIR_VARIABLE
    from quadwind_trl.envs import compile_cache

    monkeypatch.delenv(compile_cache.COMPILE_CACHE_ENV, raising=False)
    monkeypatch.delenv(CACHE_DIR_VARIABLE, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    here = compile_cache.compile_cache_dir()
    assert here.parent == tmp_path / "xdg" / "quadwind_trl" / "compile" and here.name.startswith(f"torch-{torch.__version__}-")
    monkeypatch.setenv(CACHE_DIR_VARIABLE, str(tmp_path / "root"))
    assert compile_cache.compile_cache_dir() == tmp_path / "root" / "compile" / here.name
    monkeypatch.setenv(compile_cache.COMPILE_CACHE_ENV, str(tmp_path / "mine"))
    assert compile_cache.compile_cache_dir() == tmp_path / "mine" / here.name
    real = compile_cache.platform_info()
    for key, other in (("cpu", "another processor"), ("aten_cpu_capability", "AVX2"), ("torch", "2.99.0")):
        monkeypatch.setattr(compile_cache, "platform_info", lambda k=key, v=other: {**real, k: v})
        assert compile_cache.compile_cache_dir().name != here.name, key


def test_an_unwritable_compile_cache_names_the_variable(tmp_path, monkeypatch):
    from quadwind_trl.envs import compile_cache

    (tmp_path / "a_file").write_text("")
    monkeypatch.setenv(compile_cache.COMPILE_CACHE_ENV, str(tmp_path / "a_file" / "cache"))
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", "unchanged")  # restored after the test
    with pytest.raises(OSError, match=compile_cache.COMPILE_CACHE_ENV):
        compile_cache.use_compile_cache()
    assert os.environ["TORCHINDUCTOR_CACHE_DIR"] == "unchanged"


@linux_only
def test_a_library_cut_short_is_seen_from_its_header(tmp_path):
    """A whole library passes; one cut anywhere (inside its header, its code, or just before its
    section table's end) and a file that is no ELF are truncated; one written within the grace
    (another process's compile in progress) is not judged."""
    size = ELF_LIBRARY.stat().st_size
    whole = _aged(_library(tmp_path / "a" / "whole.so"))
    cut = [_aged(_library(tmp_path / "b" / f"cut_{n}.so", n)) for n in (0, 30, 100, size // 2, size - 1)]
    junk = tmp_path / "c" / "junk.so"
    junk.parent.mkdir()
    junk.write_bytes(b"not a library")
    _aged(junk)
    fresh = _library(tmp_path / "d" / "fresh.so", 100)
    found = compile_cache.truncated_libraries(tmp_path)
    assert found == sorted([*cut, junk]) and whole not in found and fresh not in found
    assert compile_cache.truncated_libraries(tmp_path, grace_s=0.0) == sorted([*cut, junk, fresh])


@linux_only
def test_a_folder_holding_a_truncated_library_is_discarded_before_the_first_compile(tmp_path, monkeypatch):
    """Pointing inductor at the cache keeps a folder of whole libraries and of libraries being
    written; one holding an old truncated library (a compile killed while writing it) is
    discarded whole, with a warning, and made again empty."""
    monkeypatch.setenv(compile_cache.COMPILE_CACHE_ENV, str(tmp_path))
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", "unchanged")  # restored after the test
    folder = compile_cache.compile_cache_dir()
    whole, being_written = _aged(_library(folder / "ab" / "whole.so")), _library(folder / "ef" / "new.so", 4096)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing to say
        assert compile_cache.use_compile_cache() == folder and os.environ["TORCHINDUCTOR_CACHE_DIR"] == str(folder)
    assert whole.exists() and being_written.exists()
    _aged(_library(folder / "cd" / "cut.so", 4096))
    with pytest.warns(RuntimeWarning, match="1 truncated library .*cd/cut.so.*discarded"):
        assert compile_cache.use_compile_cache() == folder
    assert folder.is_dir() and not any(folder.iterdir()) and not list(tmp_path.glob("*.discarded-*"))


def test_a_failure_naming_no_file_discards_the_whole_folder(tmp_path, monkeypatch):
    """A compile failure that names no file of the cache (a truncated Python module fails with a
    message about its content) leaves nothing of the folder to trust: it is replaced by an empty
    one; one that names a file deletes that file alone."""
    import torch._dynamo.exc

    monkeypatch.setenv(compile_cache.COMPILE_CACHE_ENV, str(tmp_path))
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", "unchanged")  # restored after the test
    folder = compile_cache.use_compile_cache()
    (folder / "wn").mkdir()
    module, other = folder / "wn" / "module.py", folder / "other.py"
    module.write_text("from ctypes import c_voi")
    other.write_text("")
    named = torch._dynamo.exc.BackendCompilerFailed("inductor", OSError(5, "input/output error", str(module)), None)
    assert compile_cache.discard_broken_entry(named) == module and not module.exists() and other.exists()
    anonymous = torch._dynamo.exc.BackendCompilerFailed("inductor", ImportError("cannot import name 'c_voi'"), None)
    assert compile_cache.discard_broken_entry(anonymous) == folder
    assert folder.is_dir() and not any(folder.iterdir()) and not list(tmp_path.glob("*.discarded-*"))


@linux_only
def test_a_compile_that_fails_on_a_broken_entry_deletes_it_and_compiles_again(monkeypatch, tmp_path):
    """A compile that fails on a file of its cache (a library truncated after the check before
    the first compile, which inductor would load because it exists) deletes that file and
    compiles once more; the step then flies as it would have. A compile that fails again is
    raised, saying where the cache is. (A real truncated library: docs/benchmarks.md, "A broken
    compile cache entry".)"""
    import torch._dynamo.exc

    from quadwind_trl.envs import compile_cache, control_step

    monkeypatch.setenv(compile_cache.COMPILE_CACHE_ENV, str(tmp_path))
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", "unchanged")  # restored after the test
    folder = compile_cache.use_compile_cache()
    broken, kept = folder / "ab" / "broken.so", folder / "cd" / "whole.so"
    for path in (broken, kept):
        path.parent.mkdir()
        path.write_bytes(ELF_LIBRARY.read_bytes())
    calls = []

    def fails_on_the_library_once(*args):
        calls.append(broken.exists())
        if len(calls) == 1:
            raise torch._dynamo.exc.BackendCompilerFailed(
                "inductor", ImportError("cannot read file data", path=str(broken)), None)
        return control_step._flat_held_control_step(*args)

    env = QuadWindEnv(EnvConfig(), batch_size=[2], compile_step=True)
    env._hold._function = fails_on_the_library_once
    eager = QuadWindEnv(EnvConfig(), batch_size=[2])
    td, td_eager = env.reset(), eager.reset()
    td["action"] = td_eager["action"] = torch.full((2, 4), 0.1)
    with pytest.warns(RuntimeWarning, match="broken.so was deleted"):
        stepped = env.step(td)
    assert calls == [True, False] and kept.exists()  # the named file went, nothing else
    expected = eager.step(td_eager)
    assert set(stepped["next"].keys(True, True)) == set(expected["next"].keys(True, True))
    for key in expected["next"].keys(True, True):
        torch.testing.assert_close(stepped["next", key], expected["next", key], rtol=0, atol=0)

    def always_fails(*args):
        raise torch._dynamo.exc.BackendCompilerFailed("inductor", RuntimeError("an inductor bug"), None)

    env._hold._function = always_fails
    with pytest.warns(RuntimeWarning), pytest.raises(torch._dynamo.exc.BackendCompilerFailed) as failed:
        env.step(stepped["next"].clone().set("action", td["action"]))
    assert any(str(compile_cache.compile_cache_dir()) in note and "again" in note for note in failed.value.__notes__)
