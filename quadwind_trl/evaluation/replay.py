"""Exact replay records: per-episode RMSEs of a sweep slice as ``float.hex`` strings.

A record pins PD on the default vehicle and the shipped policy (wind-blind and wind-aware) of the
sweep's regime on the same episodes, flown in one batch of the slice's size. A change that claims
"no physics change" must reproduce every value (``recipes/replay_slice.py``,
``tests/test_replay.py``).
"""
from __future__ import annotations

from ..config import EnvConfig
from ..envs import QuadWindEnv
from ..envs.runner import fly
from ..estimator import load_estimator
from ..manifest import CHECKPOINT_DIR
from ..regimes import SWEEP_REGIME, SWEEPS
from .ablation import fly_controllers
from .tracking import sweep_setup

METRICS = ("rmse_xy", "rmse_z")


def replay(sweep_name: str, rows: slice, quick: bool) -> dict[str, dict[str, list[str]]]:
    """Per-controller, per-metric ``float.hex`` of every episode of ``rows`` of the sweep."""
    sweep, regime = SWEEPS[sweep_name], SWEEP_REGIME[sweep_name]
    scenarios, override = sweep_setup(sweep, quick)
    scenarios = scenarios[rows]
    n = scenarios.batch_size[0]
    pd_cfg = override(EnvConfig()) if override else EnvConfig()
    results = {"pd": fly(QuadWindEnv(pd_cfg, batch_size=[n]), scenarios, progress=False)}
    results.update(fly_controllers(regime, scenarios, CHECKPOINT_DIR / f"policy_{regime}.pt",
                                   load_estimator(regime), ("blind", "aware"), config_override=override))
    return {name: {m: [float(v).hex() for v in getattr(res, m).tolist()] for m in METRICS} | {
        "crashed": res.crashed.tolist()} for name, res in results.items()}


def mismatches(reference: dict, flown: dict) -> tuple[list[tuple[str, str, int]], int]:
    """``(differing (controller, metric, episode) triples, number of values compared)``."""
    differ = [(name, m, i) for name, block in reference.items() for m, values in block.items()
              for i, v in enumerate(values) if flown[name][m][i] != v]
    return differ, sum(len(values) for block in reference.values() for values in block.values())
