"""Paired evaluation: several controllers fly the same scenarios on identical replayed physics.

An episode is fully defined by its scenario row (trajectory, wind, turbulence and sensor seeds,
initial state), so flying one scenario batch with different controllers, each in an env of the
same batch size, gives each controller exactly the same world (``docs/simulator.md``, exact
replay). :func:`fly_paired` is that primitive; the trainer's periodic evaluation against PD
(:mod:`quadwind_trl.rl.trainer`) and the ablation (:mod:`quadwind_trl.evaluation.ablation`) both
fly through it. :func:`improvement` and :func:`win_rate` are the paired statistics both report;
the bootstrap and the decomposition built on them are in :mod:`quadwind_trl.evaluation.statistics`.
"""
from __future__ import annotations

from contextlib import contextmanager
from typing import Callable, Iterator, Mapping, Sequence

import torch
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.envs import EnvBase, TransformedEnv, VecNormV2

from ..envs.runner import FlightResults, NestedKey, fly

Policy = Callable[[TensorDictBase], TensorDictBase]
Flight = tuple[EnvBase, Policy | None]  # (env, policy); policy None flies the PD baseline


def improvement(baseline: Tensor, other: Tensor) -> float:
    """Reduction in mean RMSE, percent: ``100 (1 - mean(other) / mean(baseline))``."""
    return 100.0 * (1.0 - other.double().mean().item() / baseline.double().mean().item())


def win_rate(baseline: Tensor, other: Tensor) -> tuple[int, int]:
    """Pairs in which ``other`` has strictly lower RMSE than ``baseline``, and the pair count."""
    return int((other < baseline).sum()), baseline.numel()


@contextmanager
def frozen_normalisation(env: EnvBase) -> Iterator[None]:
    """Observation normalisation frozen while flying (evaluation must not update it), restored after."""
    norms = [t for t in env.transform if isinstance(t, VecNormV2)] if isinstance(env, TransformedEnv) else []
    was_frozen = [vn.frozen for vn in norms]
    for vn in norms:
        vn.freeze()
    try:
        yield
    finally:
        for vn, frozen in zip(norms, was_frozen):
            vn.frozen = frozen


def fly_paired(
    flights: Mapping[str, Flight],
    scenarios: TensorDictBase,
    log_keys: Sequence[NestedKey] = ("step",),
    progress: bool | None = False,
    chunks: range | None = None,
) -> dict[str, FlightResults]:
    """Deterministic flights of ``scenarios`` by each ``name: (env, policy)`` of ``flights``, in
    that order, normalisation frozen; results per name, rows in scenario order. The envs must have
    the same batch size for the episodes to be bitwise the same worlds. ``chunks``: only these
    batches of the flight order (:func:`~quadwind_trl.envs.runner.iter_flights`)."""
    sizes = {name: env.batch_size[0] for name, (env, _) in flights.items()}
    if len(set(sizes.values())) > 1:
        raise ValueError(f"fly_paired: envs of one batch size replay identical episodes; got batch sizes {sizes}")
    out = {}
    for name, (env, policy) in flights.items():
        with frozen_normalisation(env):
            out[name] = fly(env, scenarios, policy=policy, log_keys=log_keys, progress=progress, chunks=chunks)
    return out


def paired_metrics(policy: FlightResults, pd: FlightResults) -> dict[str, float]:
    """Mean RMSE and improvement vs PD on matched episodes (paper: 1 - mean RL / mean PD)."""
    out = {}
    for name in ("rmse_xy", "rmse_z", "rmse"):
        rl, base = getattr(policy, name).double(), getattr(pd, name).double()
        out[name] = float(rl.mean())
        out[f"pd_{name}"] = float(base.mean())
        out[f"improvement_{name}_pct"] = improvement(base, rl)
    out["improvement_vs_pd"] = out["improvement_rmse_pct"]
    wins, pairs = win_rate(pd.rmse, policy.rmse)
    out["win_rate"] = wins / pairs
    out["crashed"] = int(policy.crashed.sum())
    out["episodes"] = int(policy.rmse.numel())
    return out


def default_eval_scenarios(regime: str, episodes: int = 5) -> TensorDictBase:
    """The trainer's small fixed evaluation set: ``episodes`` rows of the regime's paper sweep,
    one per trajectory first, spread over the wind levels (held-out design seed, like the sweep)."""
    from ..regimes import HORIZONTAL_SWEEP, VERTICAL_SWEEP

    sweep = HORIZONTAL_SWEEP if regime == "horizontal" else VERTICAL_SWEEP
    sc = sweep.scenarios()
    n = sc.batch_size[0]
    t = len(sweep.trajectories)
    cases = n // t
    # case-major, trajectory-minor: pick case c_i (spread over the grid) for trajectory i % t
    rows = []
    for i in range(episodes):
        case = (i * (cases // max(episodes, 1)) + 7 * i) % cases
        rows.append(case * t + (i % t))
    return sc[torch.tensor(rows)].exclude("case_id", "seed_index")
