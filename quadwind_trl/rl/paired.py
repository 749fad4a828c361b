"""Paired evaluation: several controllers fly the same scenarios on identical replayed physics.

An episode is fully defined by its scenario row (trajectory, wind, turbulence and sensor seeds,
initial state), so flying one scenario batch with different controllers, each in an env of the
same batch size, gives each controller exactly the same world (``docs/simulator.md``, exact
replay). :func:`fly_paired` is that primitive; the trainer's periodic evaluation against PD
(:mod:`quadwind_trl.rl.trainer`) and the ablation (:mod:`quadwind_trl.evaluation.ablation`) both
fly through it. :func:`improvement` and :func:`win_rate` are the paired statistics both report,
:func:`validation_score` the rule training keeps its policy by;
the bootstrap and the decomposition built on them are in :mod:`quadwind_trl.evaluation.statistics`.
"""
from __future__ import annotations

import math
from contextlib import contextmanager
from typing import Callable, Iterator, Mapping, Sequence

import torch
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.envs import EnvBase, TransformedEnv, VecNormV2

from ..envs.runner import FlightResults, NestedKey, fly

Policy = Callable[[TensorDictBase], TensorDictBase]
Flight = tuple[EnvBase, Policy | None]  # (env, policy); policy None flies the PD baseline
VALIDATION_TAIL_FRACTION = 0.1  # the share of worst validation episodes the selection rule adds


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
    out["rmse_worst"] = float(policy.rmse.max())
    out["pd_rmse_worst"] = float(pd.rmse.max())
    out["validation_score"] = validation_score(policy.rmse)
    out["crashed"] = int(policy.crashed.sum())
    out["episodes"] = int(policy.rmse.numel())
    return out


def validation_score(rmse: Tensor) -> float:
    """The model-selection rule (lower is better, m): the mean episode RMSE plus the mean RMSE of
    the worst :data:`VALIDATION_TAIL_FRACTION` of the episodes (at least one). The tail term prices
    the rare lost flight that a mean over 45 episodes would average away."""
    rmse = rmse.double().flatten()
    worst = rmse.topk(max(1, math.ceil(VALIDATION_TAIL_FRACTION * rmse.numel()))).values
    return float(rmse.mean() + worst.mean())


def validation_scenarios(regime: str, episodes: int | None = None) -> TensorDictBase:
    """The regime's validation sweep (:data:`~quadwind_trl.regimes.VALIDATION_SWEEPS`), on which
    training evaluates and selects its policy; ``episodes``: an evenly spread subset of it (smoke
    runs and tests), first and last rows included."""
    from ..regimes import VALIDATION_SWEEPS

    if regime not in VALIDATION_SWEEPS:
        raise ValueError(f"regime={regime!r}; allowed: {', '.join(repr(r) for r in VALIDATION_SWEEPS)}")
    sc = VALIDATION_SWEEPS[regime].scenarios().exclude("case_id", "seed_index")
    n = sc.batch_size[0]
    if episodes is None or episodes == n:
        return sc
    if not 1 <= episodes <= n:
        raise ValueError(f"episodes={episodes}; allowed: 1 to {n} (the {regime} validation sweep), or None for all")
    return sc[torch.linspace(0, n - 1, episodes).round().long()]
