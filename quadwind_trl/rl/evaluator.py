"""The trainer's periodic evaluation against PD, in the training process or beside it.

:func:`evaluate_against_pd` is the evaluation itself: the deterministic policy under the training
normalisation, frozen, against PD on the same replayed episodes (PD flown once and reused: its
flights never change; :mod:`~quadwind_trl.rl.pd_flights` keeps them for later runs too).
:class:`BackgroundEvaluator` runs that same function in a child process
(``PPOConfig.background_eval``): training goes on while a snapshot of the policy flies, so on a
machine whose collection leaves a core idle the evaluations stop adding to the run's wall time.
The child builds its eval env from the trainer's :class:`~quadwind_trl.rl.envs.EnvFactory` with
the same seed and batch size, and flies on the run's thread count, so its metrics are those the
training process would compute (``tests/test_ppo.py``); training never waits for it except where a
run ends.

Snapshots and results cross the process boundary as ``torch.save`` bytes: a copy taken at
submission, so the update that follows cannot change what is evaluated.
"""
from __future__ import annotations

import io
import multiprocessing as mp
import queue
import time
import traceback
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.envs import TransformedEnv

from ..envs.runner import FlightResults
from .config import PPOConfig
from .envs import EnvFactory, RLEnvSpec, load_vecnorm_state
from .paired import Policy, fly_paired, paired_metrics
from .pd_flights import pd_evaluation

# how long the parent waits for an idle child to exit after asking it to, s (then it is terminated)
_CLOSE_TIMEOUT_S = 120.0


def evaluate_against_pd(env: TransformedEnv, spec: RLEnvSpec, actor: Policy, vecnorm_state: dict,
                        scenarios: TensorDictBase, pd_eval: dict | None) -> tuple[dict[str, float], dict]:
    """``(metrics, pd_eval)``: :func:`~quadwind_trl.rl.paired.paired_metrics` of ``actor`` against
    PD on ``scenarios`` in ``env`` (built from ``spec``) under the normalisation ``vecnorm_state``
    (frozen), and PD's per-episode results (``pd_eval``; when None, from
    :func:`~quadwind_trl.rl.pd_flights.pd_evaluation`: kept from an earlier run, or flown here),
    plus ``eval_s``, the seconds it took."""
    load_vecnorm_state(env, vecnorm_state)
    t0 = time.perf_counter()
    if pd_eval is None:
        pd_eval = pd_evaluation(env, spec, scenarios)
    policy = fly_paired({"policy": (env, actor)}, scenarios)["policy"]
    pd = FlightResults(**pd_eval, log=TensorDict({}, batch_size=[pd_eval["index"].numel(), 0]))
    metrics = paired_metrics(policy, pd)
    metrics["eval_s"] = time.perf_counter() - t0
    return metrics, pd_eval


def to_bytes(obj) -> bytes:
    buffer = io.BytesIO()
    torch.save(obj, buffer)
    return buffer.getvalue()


def from_bytes(data: bytes):
    return torch.load(io.BytesIO(data), weights_only=True)


@dataclass(frozen=True)
class EvaluationResult:
    """One finished background evaluation: the snapshot's frame count, its metrics, PD's results."""

    frames: int
    metrics: dict[str, float]
    pd_eval: dict


@torch.no_grad()  # as the flights are flown (runner.fly): grad mode is part of what the step's graph is traced under
def _step_once_aside(factory: EnvFactory, scenarios: TensorDictBase, seed: int) -> None:
    """One step of the zero action on a throwaway copy of the eval env, on ``scenarios``: the
    child's compiled step is traced (or read from inductor's cache, about ten seconds) while the
    trainer collects its first batches, not at the first evaluation, which a run evaluated once
    at its end waits for. The copy's simulator is its own, and the compiled step is the process's
    (one for every env of the configuration): the eval env's flights are unchanged. Eagerly it
    costs one step."""
    aside = factory(num_envs=scenarios.batch_size[0], seed=seed, desync_steps=0)
    sim = aside.base_env
    td = sim.reset(scenario=scenarios.to(sim.device))  # where the flights put them (runner.fly)
    sim.step(td.update(sim.full_action_spec.zero()))
    aside.close()


def _serve(factory: EnvFactory, scenarios: TensorDictBase, cfg: PPOConfig, seed: int, jobs: mp.Queue, results: mp.Queue
           ) -> None:
    """The child: build the eval env and an actor once, then evaluate each job until ``None``."""
    from .policy import build_actor_critic, network_dims

    try:
        if cfg.threads:
            torch.set_num_threads(cfg.threads)
        env = factory(num_envs=scenarios.batch_size[0], seed=seed, desync_steps=0)
        actor = build_actor_critic(cfg, **network_dims(factory.spec))[0].to(factory.spec.device)
        _step_once_aside(factory, scenarios, seed)
        pd_eval = None
        while (job := jobs.get()) is not None:
            job = from_bytes(job)
            policy_file = from_bytes(job["policy_file"])
            actor.load_state_dict(policy_file["policy"])
            metrics, pd_eval = evaluate_against_pd(env, factory.spec, actor, policy_file["vecnorm"], scenarios,
                                                  job["pd_eval"] or pd_eval)
            results.put(("done", to_bytes({"frames": job["frames"], "metrics": metrics, "pd_eval": pd_eval})))
        env.close()
    except BaseException:  # the parent raises it, with this traceback
        results.put(("error", traceback.format_exc()))


class BackgroundEvaluator:
    """:func:`evaluate_against_pd` in a child process, one snapshot after another, in the order
    submitted. ``factory``, ``scenarios`` and ``seed`` build the eval env the training process
    would (``factory(num_envs=len(scenarios), seed=seed, desync_steps=0)``); ``cfg`` gives the
    actor's architecture and the thread count."""

    def __init__(self, factory: EnvFactory, scenarios: TensorDictBase, cfg: PPOConfig, seed: int):
        ctx = mp.get_context("spawn")  # a fresh interpreter: no state of the trainer's is inherited
        self._jobs, self._results = ctx.Queue(), ctx.Queue()
        self._process = ctx.Process(target=_serve, args=(factory, scenarios, cfg, seed, self._jobs, self._results),
                                    name="background-eval", daemon=True)
        self._process.start()
        self.pending = 0

    def submit(self, frames: int, policy_file: bytes, pd_eval: dict | None) -> None:
        """Evaluate the snapshot ``policy_file`` (:func:`to_bytes` of a
        :func:`~quadwind_trl.rl.policy.policy_payload`: the actor's weights and the normalisation),
        taken at ``frames``; ``pd_eval``: PD's results when known (None: the child flies PD, once)."""
        job = {"frames": frames, "policy_file": policy_file, "pd_eval": pd_eval}
        self._jobs.put(to_bytes(job))
        self.pending += 1

    def receive(self, wait: bool = False) -> list[EvaluationResult]:
        """The evaluations finished so far, oldest first; with ``wait``, every one submitted."""
        out = []
        while self.pending:
            try:
                kind, payload = self._results.get(block=wait, timeout=1.0 if wait else None)
            except queue.Empty:
                if self._process.is_alive():
                    if not wait:
                        break
                    continue
                try:  # what it wrote as it exited (its error), else it was killed (e.g. out of memory)
                    kind, payload = self._results.get(timeout=1.0)
                except queue.Empty:
                    raise RuntimeError(f"the background evaluation process died (exit code {self._process.exitcode}) "
                                       f"with {self.pending} evaluations in flight") from None
            if kind == "error":
                raise RuntimeError(f"background evaluation failed:\n{payload}")
            self.pending -= 1
            out.append(EvaluationResult(**from_bytes(payload)))
        return out

    def close(self) -> None:
        """Stop the child: at once when evaluations are still in flight (a run that failed or was
        interrupted; a resumed run flies them again), otherwise once it has read the stop."""
        if self._process.is_alive():
            if not self.pending:
                self._jobs.put(None)
                self._process.join(_CLOSE_TIMEOUT_S)
            if self._process.is_alive():
                self._process.terminate()
                self._process.join()
        # jobs a stopped child never read would keep the queue's feeder thread blocked on a full
        # pipe, and this process from exiting: the child is gone, so they are dropped
        self._jobs.cancel_join_thread()
        self._jobs.close()
        self._results.close()
