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
* dynamo's guards on tensordict's tensorclass memo are dropped (:func:`_without_tensorclass_memo`):
  a graph traced once stays valid for the process, whatever classes its other code meets;
* what is traced is the graph the step has always had: the eager step's shortcuts (numbers made
  tensors, fused ops) are taken only eagerly (:mod:`.operands`);
* inductor's caches (the FX graph and AOTAutograd caches, on by default) keep the compiled code
  on disk, in :func:`compile_cache_dir` (the user's cache folder): a later process on the same
  machine traces the step again (dynamo's part) but compiles no C++ (minutes).
"""
from __future__ import annotations

import functools
import warnings
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, NamedTuple

import torch
from tensordict import TensorDict
from torch import Tensor

from .compile_cache import compile_cache_dir, discard_broken_entry, use_compile_cache
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

    use_compile_cache()
    cfg = torch._dynamo.config
    cfg.recompile_limit = max(cfg.recompile_limit, COMPILED_STEPS_PER_PROCESS)
    return torch.compile(_flat_held_control_step, dynamic=None if dynamic else False,
                         options={"guard_filter_fn": _without_tensorclass_memo})


# tensordict caches "is this class a tensorclass" in a module-level dict that grows whenever any
# code of the process asks about a class it has not seen. Dynamo guards on that dict's length
# wherever a traced TensorDict reads it, so its growth threw the whole step away: a full retrace
# at a training run's second batch, and at the evaluation process's first flight. A class's answer
# never changes (it is fixed when the class is made), so the guards on the cache protect nothing
# the graph depends on.
_TENSORCLASS_MEMO = "_TENSORCLASS_MEMO"


def _without_tensorclass_memo(guards: Sequence) -> list[bool]:
    """Dynamo's guard filter: every guard of the step kept except those on tensordict's memo."""
    return [_TENSORCLASS_MEMO not in guard.name for guard in guards]


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


def held_control_steps(sim: QuadSimulator, task: Task, params: TensorDict, state: TensorDict, action: Tensor,
                       wind_ne: Tensor | None, reward: Tensor, steps: Tensor, terminated: Tensor, truncated: Tensor,
                       count: int = 1) -> tuple[TensorDict, Tensor, Tensor, Tensor, Tensor]:
    """``count`` control steps of one held action (:func:`held_control_step`), eagerly, from the
    running totals given. The first starts with no row ended: its merge would select the whole
    new state (a select per state leaf), and is skipped."""
    for k in range(count):
        state, reward, steps, terminated, truncated = held_control_step(
            sim, task, params, state, action, wind_ne, reward, steps, terminated, truncated, merge=k > 0)
    return state, reward, steps, terminated, truncated


class CompiledControlStep:
    """:func:`held_control_steps` of ``sim`` and ``task`` through the process's compiled step
    (module docstring); called as the eager one, without ``sim`` and ``task``. Every control step
    is one call of the compiled :func:`held_control_step`, its merge included (no row has ended
    at the first, and the merge then selects the new state: one graph serves every control step).
    The params and state cross as leaves: flattened once per call and rebuilt once, not at every
    control step (at N = 64, flattening, rebuilding and the nested TensorDicts cost about an
    eighth of a compiled control step).
    ``dynamic``: the batch dimension symbolic (one graph for every ``N``), else static sizes."""

    def __init__(self, sim: QuadSimulator, task: Task, dynamic: bool = True):
        self.sim, self.task, self.dynamic = sim, task, dynamic
        self._function = _compiled_function(dynamic)
        self._layout: _Layout | None = None

    def __call__(self, params: TensorDict, state: TensorDict, action: Tensor, wind_ne: Tensor | None,
                 reward: Tensor, steps: Tensor, terminated: Tensor, truncated: Tensor,
                 count: int = 1) -> tuple[TensorDict, Tensor, Tensor, Tensor, Tensor]:
        first = self._layout is None
        if first:  # the keys are the config's: the same at every step
            self._layout = _Layout(_leaf_keys(params), _leaf_keys(state))
        layout = self._layout
        params_leaves = tuple(entry(params, *k) for k in layout.params)
        state_leaves = tuple(entry(state, *k) for k in layout.state)
        totals = (reward, steps, terminated, truncated)
        for k in range(count):
            state_leaves, *totals = self._step(params_leaves, state_leaves, action, wind_ne, totals, first and k == 0)
        return (_rebuild(layout.state, state_leaves, state.batch_size), *totals)

    def _step(self, params_leaves: tuple[Tensor, ...], state_leaves: tuple[Tensor, ...], action: Tensor,
              wind_ne: Tensor | None, totals: tuple[Tensor, ...], first: bool) -> tuple:
        """One compiled control step on the leaves: the new state's leaves and the four totals."""
        leaves = _distinct((*params_leaves, *state_leaves))
        params_leaves, state_leaves = leaves[:len(params_leaves)], leaves[len(params_leaves):]
        if first and self.dynamic:  # a graph traced with N symbolic keeps it so: later calls need no marks
            for leaf in (*leaves, action, *totals, *(() if wind_ne is None else (wind_ne,))):
                torch._dynamo.maybe_mark_dynamic(leaf, 0)
        args = (self.sim, self.task, self._layout, params_leaves, state_leaves, action, wind_ne, *totals)
        try:
            return self._function(*args)
        except torch._dynamo.exc.BackendCompilerFailed as error:
            # a broken cache entry that the check before the first compile could not see (one
            # younger than its grace, a module rather than a library) is deleted and the step
            # compiled once more (.compile_cache); a compile that fails again is inductor's own
            # failure, not the cache's
            warnings.warn(f"the step's compile failed ({type(error.inner_exception).__name__}: "
                          f"{error.inner_exception}); {discard_broken_entry(error)} was deleted from its cache and "
                          "the step is compiled again", RuntimeWarning, stacklevel=3)
            try:
                return self._function(*args)
            except torch._dynamo.exc.BackendCompilerFailed as again:
                again.add_note(f"the compiled step failed to compile again after its broken cache entry was deleted "
                               f"(cache: {compile_cache_dir()}): where it names a file there, delete that folder; "
                               "else the cause is not the cache")
                raise
