"""One single-threaded simulator process per core: TorchRL's ``ParallelEnv`` of ``QuadWindEnv``\\ s.

    env = parallel_env(2, 4096)            # batch [2, 2048]: two workers of 2,048 rows each
    td = env.reset()

torch runs one batched step on one core far better than on two (the step is ~200 short loops,
each ending in a barrier: two threads contend). The way to use both cores is one
single-threaded process per core, each stepping its share of the rows: :func:`parallel_env`.

TorchRL 0.14's ``ParallelEnv`` makes its parent process poll the workers' done flags in a tight
loop while they step (``ParallelEnv._wait_for_workers``), which keeps one core busy doing
nothing. With as many workers as cores, the workers then share what is left. Measured at
N = 4096 on this project's 2-core machine (compiled, 10 control steps per env step, 1 thread per
worker): one process 357k control steps/s; two workers under ``ParallelEnv`` 388k; the same two
workers with the parent sleeping between polls (:class:`QuietParallelEnv`) 527k
(``bench/env_throughput.py --workers``, ``docs/benchmarks.md``).

Worker ``i`` holds rows ``i N / W ... (i + 1) N / W - 1`` of the batch (``QuadWindEnv(first_row=)``),
so the workers together draw exactly the episodes one ``QuadWindEnv`` of all N rows and the same
``seed`` would (``tests/test_env.py`` checks that they fly them identically). Calling
``set_seed`` on the parallel env instead hands each worker a seed of TorchRL's choosing.
"""
from __future__ import annotations

import time
from functools import partial

import torch
from torchrl.envs import ParallelEnv

from ..config import EnvConfig
from .quad_env import QuadWindEnv


class QuietParallelEnv(ParallelEnv):
    """``ParallelEnv`` whose parent sleeps ``poll_s`` between looks at the workers' done flags
    instead of spinning (see the module docstring). Everything else is TorchRL's."""

    poll_s = 1e-4  # s; an env step of a worker takes milliseconds, so this costs < 1 % in latency
    _health_every = 1000  # polls between checks that the workers are alive (~0.1 s)

    def _wait_for_workers(self, workers_range):
        if not self._use_buffers:  # the pipe path already blocks in the OS
            return super()._wait_for_workers(workers_range)
        flags, index = self._shm_done_flags, self._worker_indices
        deadline = time.time() + self.BATCHED_PIPE_TIMEOUT
        polls = 0
        while not all(flags[index[i]] for i in workers_range):
            time.sleep(self.poll_s)
            polls += 1
            if polls % self._health_every == 0:
                dead = [i for i in workers_range if not flags[index[i]] and not self._workers[i].is_alive()]
                if dead:
                    self._shutdown_workers()
                    raise RuntimeError(f"QuietParallelEnv: worker(s) {dead} died")
                if time.time() > deadline:
                    raise RuntimeError(f"QuietParallelEnv: the workers did not finish within {self.BATCHED_PIPE_TIMEOUT} s "
                                       "(BATCHED_PIPE_TIMEOUT)")
        for i in workers_range:
            flags[index[i]] = 0


def _worker_env(num_envs: int, config: EnvConfig | None, threads: int, env_kwargs: dict, first_row: int) -> QuadWindEnv:
    torch.set_num_threads(threads)
    return QuadWindEnv(config, batch_size=[num_envs], first_row=first_row, **env_kwargs)


def parallel_env(
    num_workers: int,
    num_envs: int,
    config: EnvConfig | None = None,
    *,
    threads_per_worker: int = 1,
    compile_step: bool = True,
    **env_kwargs,
) -> QuietParallelEnv:
    """``num_workers`` processes of ``num_envs / num_workers`` rows each (batch
    ``[num_workers, num_envs // num_workers]``), each a :class:`QuadWindEnv` with
    ``threads_per_worker`` torch threads; ``env_kwargs`` go to every worker's ``QuadWindEnv``
    (``seed``, ``scenario_sampler``, ``device``, ``task``, ...)."""
    if num_workers < 1:
        raise ValueError(f"parallel_env: num_workers={num_workers}; allowed: >= 1")
    if num_envs < num_workers or num_envs % num_workers:
        raise ValueError(f"parallel_env: num_envs={num_envs} must be a positive multiple of num_workers={num_workers}")
    if threads_per_worker < 1:
        raise ValueError(f"parallel_env: threads_per_worker={threads_per_worker}; allowed: >= 1")
    rows = num_envs // num_workers
    makers = [partial(_worker_env, rows, config, threads_per_worker, {"compile_step": compile_step, **env_kwargs}, i * rows)
              for i in range(num_workers)]
    return QuietParallelEnv(num_workers, makers)
