"""A batch's rows stepped by Ray actors, on any node of a Ray cluster: :class:`RayRowsEnv`.

    env = RayRowsEnv([partial(make_rows, i) for i in range(2)])   # batch [2, rows]: two actors
    td = env.reset()

It is :class:`~quadwind_trl.envs.parallel.QuietParallelEnv`'s row split with Ray actors in place
of local processes: actor ``i`` builds its env from ``makers[i]`` (typically rows
``i N / K ... (i + 1) N / K - 1`` of one batch, ``QuadWindEnv(first_row=)``), and this env, in the
driver, stacks their outputs into a batch ``[K, rows]``. The policy, the transforms that pool
every row (the observation normalisation) and the collector stay in the driver, exactly as with
local workers: only the row-wise work travels.

Each call mirrors what ``ParallelEnv`` asks of its workers, so a batch collected through it is
the batch local workers would collect, bit for bit (``tests/test_ray_collection.py``):

* ``step``: every actor steps its rows on the action (and state) entries of its slice, and
  returns the ``"next"`` entries;
* ``reset``: only the actors holding a row to restart are called, with their slice of the reset
  mask; the others' rows keep their last outputs (the caller merges only the restarted rows).

The actors are created here with ``num_cpus`` CPUs each and end with :meth:`RayRowsEnv.close`.
Ray is imported when a :class:`RayRowsEnv` is built, not with this module: the caller connects
first (``quadwind_trl.ray_cluster.connect``). Tensors travel through Ray on the CPU.
"""
from __future__ import annotations

import time
from typing import Any, Callable, Sequence

import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase


class RowsActor:
    """What runs in one Ray actor: one env of rows, stepped on request (see the module docstring)."""

    def __init__(self, make_env: Callable[[], EnvBase]):
        self.env = make_env()
        self.busy_s = 0.0  # s spent in the env's reset and step (the actor's share of collection)

    def specs(self) -> tuple[TensorDictBase, TensorDictBase, str]:
        """The env's output and input specs (on the CPU) and the node it runs on."""
        import socket

        return self.env.output_spec.clone().cpu(), self.env.input_spec.clone().cpu(), socket.gethostname()

    def reset(self, td: TensorDictBase | None) -> TensorDictBase:
        t0 = time.perf_counter()
        out = self.env.reset(None if td is None else td.to(self.env.device))
        self.busy_s += time.perf_counter() - t0
        return out.cpu()

    def step(self, td: TensorDictBase) -> TensorDictBase:
        t0 = time.perf_counter()
        out = self.env.step(td.to(self.env.device)).get("next")
        self.busy_s += time.perf_counter() - t0
        return out.cpu()

    def call(self, method: str, *args: Any) -> Any:
        """``env.<method>(*args)``: what ``ParallelEnv`` forwards to each worker."""
        return getattr(self.env, method)(*args)

    def usage(self) -> tuple[float, float]:
        """(s spent resetting and stepping the rows, CPU s of this actor's process), so far."""
        return self.busy_s, time.process_time()

    def close(self) -> None:
        self.env.close()


class RayRowsEnv(EnvBase):
    """``len(makers)`` Ray actors, each holding the env ``makers[i]()`` (batch ``[rows]``, the same
    for all), stepped together as one env of batch ``[len(makers), rows]`` (module docstring).

    Args:
        makers: picklable env constructors, one per actor; each runs in its actor.
        num_cpus: CPUs each actor asks Ray for (the node's scheduler counts them as taken).
        device: where this env's outputs go (the actors' envs choose their own).
        actor_options: further ``ray.remote`` options of each actor (memory, resources, ...).
    """

    def __init__(self, makers: Sequence[Callable[[], EnvBase]], *, num_cpus: float = 1,
                 device: torch.device | str = "cpu", actor_options: dict | None = None):
        import ray

        if not makers:
            raise ValueError("RayRowsEnv: makers is empty; allowed: one env constructor per actor, at least one")
        actor = ray.remote(RowsActor).options(num_cpus=num_cpus, **(actor_options or {}))
        actors = [actor.remote(make) for make in makers]
        answers = ray.get([a.specs.remote() for a in actors])  # waits for every actor to have built its env
        output_spec, input_spec, _ = answers[0]
        super().__init__(device=device, batch_size=torch.Size([len(actors), output_spec.shape[0]]))
        self._actors = actors
        self.nodes = [node for _, _, node in answers]  # the host each actor runs on, in actor order
        batched = lambda spec: spec.expand(len(actors), *spec.shape).to(self.device)  # noqa: E731
        self.full_observation_spec = batched(output_spec["full_observation_spec"])
        self.full_reward_spec = batched(output_spec["full_reward_spec"])
        self.full_done_spec = batched(output_spec["full_done_spec"])
        self.full_action_spec = batched(input_spec["full_action_spec"])
        self.full_state_spec = batched(input_spec["full_state_spec"])
        self._last: TensorDictBase | None = None  # the last outputs: what a reset gives the rows it skips
        # s this process has waited for the actors since they started (their work, the transport,
        # and the slowest one's lead on the others)
        self.wait_s = 0.0

    def _get(self, refs: list) -> list:
        import ray

        t0 = time.perf_counter()
        try:
            return ray.get(refs)
        finally:
            self.wait_s += time.perf_counter() - t0

    def _input_keys(self) -> list:
        return [*self.full_action_spec.keys(True, True), *self.full_state_spec.keys(True, True)]

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        # by design: the collector steps every row each time (ended rows restart through
        # ``_reset``, as in the one-process env, which has no partial step either); a subset step
        # would fly other rows than the one-process run it must equal bit for bit, so it is refused
        if tensordict.get("_step", None) is not None:
            raise NotImplementedError("RayRowsEnv steps every row at once; a partial step ('_step') is not supported")
        inputs = tensordict.select(*self._input_keys(), strict=False).cpu()
        out = torch.stack(self._get([a.step.remote(inputs[i]) for i, a in enumerate(self._actors)]), 0).to(self.device)
        self._last = out
        return out

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        mask = None if tensordict is None else tensordict.get("_reset", None)
        # before any output every actor answers (there are no last outputs to give the others)
        restart = (torch.ones(len(self._actors), dtype=torch.bool) if mask is None or self._last is None
                   else mask.reshape(len(self._actors), -1).any(-1).cpu())
        if tensordict is not None and not tensordict.is_empty():
            tensordict = tensordict.cpu()
        refs = {i: a.reset.remote(None if tensordict is None or tensordict.is_empty() else tensordict[i])
                for i, a in enumerate(self._actors) if restart[i]}
        fresh = dict(zip(refs, self._get(list(refs.values()))))
        keys = [*self.full_observation_spec.keys(True, True), *self.full_done_spec.keys(True, True)]
        rows = [fresh[i].select(*keys) if i in fresh else self._last[i].select(*keys) for i in range(len(self._actors))]
        # a new tensordict: the last step's outputs are the caller's "next" entries, not to be overwritten
        self._last = torch.stack(rows, 0).to(self.device)
        return self._last

    def _set_seed(self, seed: int | None) -> None:
        # by design: each actor's env is seeded by its constructor (its rows of one seeded batch);
        # a seed of TorchRL's choosing per actor would fly other episodes than the one-process env,
        # so ``set_seed`` is refused rather than silently breaking the row-for-row equality
        raise NotImplementedError("RayRowsEnv: seed the rows through their constructors (makers)")

    def call(self, method: str, *args: Any) -> list:
        """``env.<method>(*args)`` in every actor, their answers in actor order (the counterpart of
        ``ParallelEnv``'s forwarding of an attribute to its workers)."""
        return self._get([a.call.remote(method, *args) for a in self._actors])

    def usage(self) -> list[tuple[float, float]]:
        """Per actor: the seconds it has spent resetting and stepping its rows so far, and its
        process's CPU seconds (the rows, and Ray's work for the actor; from its start)."""
        return self._get([a.usage.remote() for a in self._actors])

    def close(self, *, raise_if_closed: bool = True) -> None:
        actors = self.__dict__.get("_actors")
        if actors:
            import ray

            self._actors = []
            try:
                ray.get([a.close.remote() for a in actors])
            except ray.exceptions.RayError:  # an actor already gone (its node lost, Ray stopped): nothing to close
                pass
            finally:
                for a in actors:
                    ray.kill(a)
        super().close(raise_if_closed=raise_if_closed)
