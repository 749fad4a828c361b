"""Exact replay: records of per-episode RMSEs of a sweep slice as ``float.hex`` strings, and the
check of an ablation results file against its re-flown batches (:func:`verify_ablation`).

A record pins PD on the default vehicle and the shipped policy (wind-blind and wind-aware) of the
sweep's regime on the same episodes, flown in one batch of the slice's size. A change that claims
"no physics change" must reproduce every value (``recipes/replay_slice.py``,
``tests/test_replay.py``).
"""
from __future__ import annotations

from pathlib import Path

from ..config import EnvConfig
from ..envs import QuadWindEnv
from ..envs.runner import fly
from ..estimator import load_estimator
from ..manifest import CHECKPOINT_DIR, ROOT
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


def _recorded(path: str | Path) -> Path:
    """A checkpoint path as a results file records it: relative to the repository
    (``manifest.repo_relative``) unless it exists from here or is absolute."""
    path = Path(path)
    return path if path.is_absolute() or path.exists() else ROOT / path


def verify_ablation(results: dict, chunks: range | None = None, policy_path=None, estimator_path=None
                    ) -> tuple[dict[str, tuple[int, int]], int]:
    """Re-fly batches ``chunks`` (default: all) of an ablation results file (``recipes/ablation.py``
    output) with its controllers, policy, estimator, flights (``--quick`` or not), simulator
    setting and batch layout, and compare every per-episode RMSE and crash flag with the file's
    episode table, exactly (the JSON holds each float32 RMSE exactly). Returns
    ``({controller: (identical values, values)}, episodes flown)``.

    Only the recorded layout replays: the simulator's rows do not depend on the batch, but the
    estimator's and the policy's matrix products round differently at other batch sizes (a
    2-episode slice of a 10-episode batch re-flown alone differed in every policy RMSE), so the unit of
    a check is one recorded batch (``results["batch"]``; files without it flew all their
    episodes in one)."""
    sweep_name = results["sweep"]
    sweep, regime = SWEEPS[sweep_name], SWEEP_REGIME[sweep_name]
    quick = bool(results.get("quick", "--quick" in results.get("command", "").split()))
    scenarios, override = sweep_setup(sweep, quick)
    policy = _recorded(policy_path or results["policy"])
    blind = results.get("blind_policy")
    estimator = load_estimator(regime, estimator_path or results.get("estimator"))
    flown = fly_controllers(regime, scenarios, policy, estimator, tuple(results["controllers"]),
                            batch=results.get("batch", results["episodes"]), config_override=override,
                            compile_step=bool(results.get("compile_step", False)), chunks=chunks,
                            blind_policy_path=None if blind is None else _recorded(blind))
    table = results["episodes_table"]
    out, episodes = {}, 0
    for name, res in flown.items():
        rows = res.index.tolist()
        episodes = len(rows)
        same = total = 0
        for metric in ("rmse_xy", "rmse_z", "rmse", "crashed"):
            values = getattr(res, metric).tolist()
            same += sum(values[i] == table[f"{name}_{metric}"][row] for i, row in enumerate(rows))
            total += len(rows)
        out[name] = (same, total)
    return out, episodes
