"""One control step of a held action with the task's view of it, eager or compiled.

:func:`held_control_step` is the pure function :class:`~quadwind_trl.envs.QuadWindEnv` runs
``TimingConfig.hold_control_steps`` times per env step. :class:`CompiledControlStep` runs it
through ``torch.compile``, one compiled function per process for every env:

* its simulator and task are passed in: dynamo guards on their constants (the config's values,
  the tensors' shapes), not on an env instance, so a second env of the same configuration and
  batch size reuses the first one's compiled step;
* the batch dimension symbolic by default (``QuadWindEnv(compile_step=True)``, or ``"dynamic"``;
  marked with ``maybe_mark_dynamic``): one graph for every ``N`` and every partial reset (``N = 1``
  gets one of its own: torch specialises sizes 0 and 1). ``compile_step="static"`` compiles one
  graph per configuration and batch size instead. The TensorDicts cross the compiled boundary as
  flat tuples of their leaves, rebuilt inside around the leaves' batch size: a TensorDict's
  ``batch_size`` is a Python constant to dynamo, which would pin ``N``;
* what is traced is the graph the step has always had: the eager step's shortcuts (numbers made
  tensors, fused ops) are taken only eagerly (:mod:`.operands`);
* inductor's caches (the FX graph and AOTAutograd caches, on by default) keep the compiled code
  on disk, in :func:`compile_cache_dir` (the user's cache folder): a later process on the same
  machine traces the step again (dynamo's part) but compiles no C++ (minutes).
"""
from __future__ import annotations

import functools
import hashlib
import json
import os
import shutil
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import torch
from tensordict import TensorDict
from torch import Tensor

from ..cache import cache_dir
from ..manifest import platform_info
from .operands import operands, tracing
from .tensordicts import entry, select_rows, unchecked

if TYPE_CHECKING:
    from .simulator import QuadSimulator
    from .task import Task

# Dynamo keeps one compiled step per configuration and batch size (static; dynamic: per
# configuration, and one for N = 1) and, past ``recompile_limit`` entries (torch's default: 8),
# runs the step eagerly for every later one, silently: an ablation of three sweeps x five
# controllers in one process has more
COMPILED_STEPS_PER_PROCESS = 64


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


def _use_compile_cache() -> Path:
    """Point inductor's caches at :func:`compile_cache_dir` (made if missing)."""
    folder = compile_cache_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OSError(f"compile cache folder {folder} cannot be made ({error.strerror}); set {COMPILE_CACHE_ENV} "
                      "to a writable folder") from error
    os.environ["TORCHINDUCTOR_CACHE_DIR"] = str(folder)
    return folder


def _discard_compile_cache() -> Path:
    """Move :func:`compile_cache_dir` aside and delete it, and forget what inductor loaded from
    it, so that the next compile starts from an empty folder. Moved first (an atomic rename), so
    that a second process never reads a half-deleted folder: it keeps the files it has open and
    finds the folder's path empty. Returns the folder."""
    from torch._inductor.utils import clear_caches

    folder = compile_cache_dir()
    stale = folder.with_name(f"{folder.name}.discarded-{os.getpid()}-{time.time_ns()}")
    try:
        folder.rename(stale)
    except FileNotFoundError:  # another process discarded it first
        pass
    shutil.rmtree(stale, ignore_errors=True)
    clear_caches()
    return _use_compile_cache()


def held_control_step(sim: QuadSimulator, task: Task, params: TensorDict, state: TensorDict, action: Tensor,
                      wind_ne: Tensor | None, reward: Tensor, steps: Tensor, terminated: Tensor, truncated: Tensor,
                      merge: bool = True) -> tuple[TensorDict, Tensor, Tensor, Tensor, Tensor]:
    """One control step of a held action, with the task's view of it, merged branch-free into
    the decision's running totals ``(state, reward sum, steps, terminated, truncated)``: a row
    whose episode ended earlier in the hold keeps its state and totals. Step and merge are one
    function so that, compiled, they are one graph (no eager merge of every state leaf per
    control step); the params do not change within an episode and are not merged.
    ``merge=False``: no row has ended (the decision's first control step), the new state is
    every row's."""
    running = ~(terminated | truncated)
    new = sim.step(params, state, action, wind_ne)
    new_terminated, new_truncated = task.done(params, new)
    new_reward = task.step_reward(params, state, new)
    if merge:
        # traced, the graph every compiled result was recorded with; eagerly the same selection
        # without TensorDict.where's per-leaf overhead
        new = new.where(running.reshape(-1), state) if tracing() else select_rows(running.reshape(-1), new, state)
    return (
        new,
        reward + torch.where(running, new_reward, operands(sim.physics_constants.zero, 0.0)),
        steps + running.to(steps.dtype),
        torch.where(running, new_terminated, terminated),
        torch.where(running, new_truncated, truncated),
    )


class _Layout(NamedTuple):
    """The leaf keys of the params and the state, in order: how their leaves are flattened."""

    params: tuple[tuple[str, ...], ...]
    state: tuple[tuple[str, ...], ...]


def _leaf_keys(td: TensorDict) -> tuple[tuple[str, ...], ...]:
    return tuple(k if isinstance(k, tuple) else (k,) for k in td.keys(True, True))


def _rebuild(keys: tuple[tuple[str, ...], ...], leaves: tuple[Tensor, ...], batch_size: torch.Size) -> TensorDict:
    """The TensorDict whose leaves ``leaves`` sit at ``keys``, of batch ``batch_size``."""
    tree: dict = {}
    for key, leaf in zip(keys, leaves):
        node = tree
        for name in key[:-1]:
            node = node.setdefault(name, {})
        node[key[-1]] = leaf

    def build(node: dict) -> TensorDict:
        return unchecked(batch_size, {k: build(v) if isinstance(v, dict) else v for k, v in node.items()})

    return build(tree)


def _flat_held_control_step(sim: QuadSimulator, task: Task, layout: _Layout, params: tuple[Tensor, ...],
                            state: tuple[Tensor, ...], action: Tensor, wind_ne: Tensor | None, reward: Tensor,
                            steps: Tensor, terminated: Tensor, truncated: Tensor):
    """:func:`held_control_step` on the params' and state's leaves (``layout``), the state's
    leaves out: what is compiled. The TensorDicts are rebuilt around the action's batch size,
    which the tracer sees as a symbol."""
    batch_size = torch.Size(action.shape[:1])
    new, reward, steps, terminated, truncated = held_control_step(
        sim, task, _rebuild(layout.params, params, batch_size), _rebuild(layout.state, state, batch_size), action,
        wind_ne, reward, steps, terminated, truncated)
    return tuple(new.get(key) for key in layout.state), reward, steps, terminated, truncated


@functools.cache
def _compiled_function(dynamic: bool) -> Callable:
    """The process's compiled :func:`_flat_held_control_step` of one kind, static sizes or a
    symbolic batch dimension (compiled at its first call, not here), with dynamo's recompile
    limit raised to :data:`COMPILED_STEPS_PER_PROCESS` and inductor's caches in
    :func:`compile_cache_dir`. Static: ``dynamic=False``, no size ever made symbolic (dynamo's
    default would make ``N`` symbolic at an env's second batch size)."""
    import torch._dynamo

    _use_compile_cache()
    cfg = torch._dynamo.config
    cfg.recompile_limit = max(cfg.recompile_limit, COMPILED_STEPS_PER_PROCESS)
    return torch.compile(_flat_held_control_step, dynamic=None if dynamic else False)


def _distinct(leaves: tuple[Tensor, ...]) -> tuple[Tensor, ...]:
    """``leaves`` with a tensor that is also an earlier leaf cloned. Dynamo guards on which inputs
    are the same object, and that changes with the episode: a start makes some entries one tensor
    (the scenario's sensor seed and the sensors' own), a partial reset or a merge separate copies,
    and each change would cost a recompilation."""
    seen: set[int] = set()
    out = []
    for leaf in leaves:
        out.append(leaf.clone() if id(leaf) in seen else leaf)
        seen.add(id(leaf))
    return tuple(out)


class CompiledControlStep:
    """:func:`held_control_step` of ``sim`` and ``task`` through the process's compiled step
    (module docstring); called as the eager one, without ``sim``, ``task`` and ``merge``.
    ``dynamic``: the batch dimension symbolic (one graph for every ``N``), else static sizes."""

    def __init__(self, sim: QuadSimulator, task: Task, dynamic: bool = True):
        self.sim, self.task, self.dynamic = sim, task, dynamic
        self._function = _compiled_function(dynamic)
        self._layout: _Layout | None = None

    def __call__(self, params: TensorDict, state: TensorDict, action: Tensor, wind_ne: Tensor | None,
                 reward: Tensor, steps: Tensor, terminated: Tensor, truncated: Tensor):
        first = self._layout is None
        if first:  # the keys are the config's: the same at every step
            self._layout = _Layout(_leaf_keys(params), _leaf_keys(state))
        layout = self._layout
        leaves = _distinct((*(entry(params, *k) for k in layout.params), *(entry(state, *k) for k in layout.state)))
        params_leaves, state_leaves = leaves[:len(layout.params)], leaves[len(layout.params):]
        totals = (reward, steps, terminated, truncated)
        if first and self.dynamic:  # a graph traced with N symbolic keeps it so: later calls need no marks
            for leaf in (*leaves, action, *totals, *(() if wind_ne is None else (wind_ne,))):
                torch._dynamo.maybe_mark_dynamic(leaf, 0)
        args = (self.sim, self.task, layout, params_leaves, state_leaves, action, wind_ne, *totals)
        try:
            new, *totals = self._function(*args)
        except torch._dynamo.exc.BackendCompilerFailed as error:
            # inductor trusts what its cache holds because it exists: a library or module truncated
            # by a compile that was killed while writing it (or a full disk) fails every later
            # compile. The cache is never the only copy of anything, so it is rebuilt: the folder
            # moved aside and the step compiled afresh, once; a compile that fails again is
            # inductor's own failure, not the cache's
            warnings.warn(f"the step's compile failed ({type(error.inner_exception).__name__}: "
                          f"{error.inner_exception}); its cache {_discard_compile_cache()} was discarded and the "
                          "step is compiled afresh", RuntimeWarning, stacklevel=2)
            try:
                new, *totals = self._function(*args)
            except torch._dynamo.exc.BackendCompilerFailed as again:
                again.add_note(f"the compiled step failed to compile with an empty cache ({compile_cache_dir()}) "
                               "too: the cause is not the cache")
                raise
        return (_rebuild(layout.state, new, state.batch_size), *totals)
