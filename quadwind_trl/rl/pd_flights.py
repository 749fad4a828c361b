"""PD's side of the trainer's evaluation: the env it flies in, and its flights kept between runs.

PD's evaluation flights depend on nothing a run learns. :func:`pd_evaluation` flies them in
:func:`pd_env` (the simulator alone, unless the base law reads the wind estimate) and keeps the
per-episode results on disk, for every later run that evaluates on the same episodes: a recipe's
seeds and levers all score against the same validation sweep, and each run flew PD's episodes
again before its first evaluation could be scored.

An entry's name digests everything PD's flights depend on (exact replay: the scenarios fix the
worlds, and the base law is the zero action): the package's source, the platform a bitwise replay
depends on (:func:`~quadwind_trl.manifest.platform_info`: processor, kernel path, BLAS, torch,
threads), the env config, the compiled or eager step, the device, the batch size and the
scenarios. Any change to them is another name, so a stale entry is never looked up. Entries live
under :func:`~quadwind_trl.cache.cache_dir` and are written through a temporary file and a
rename, so two processes may write one at once; one that cannot be read, or does not fit its
scenarios, is flown again and replaced, never trusted; a cache folder that cannot be written is
done without. A base law that reads the wind estimate flies every time: its flights depend on
the estimator too.
"""
from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path

import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase, TransformedEnv

from ..cache import cache_dir
from ..config import config_to_dict
from ..manifest import platform_info, save_atomic
from .envs import RLEnvSpec
from .paired import fly_paired

# PD's per-episode results an evaluation scores the policy against (``pd_eval``)
PD_EVAL_KEYS = ("index", "rmse_xy", "rmse_z", "crashed")


def pd_env(env: TransformedEnv) -> EnvBase:
    """The env PD flies in beside a policy flying ``env``: the simulator alone (``env.base_env``)
    unless its base law reads the wind estimate. PD's action is zero whatever the observation, so
    the policy's input pipeline (the estimator's ticks, the observation, its normalisation) would
    change nothing it flies, and cost a fifth to a third of its flights' CPU time
    (docs/benchmarks.md); the simulator is the same object, so PD's episodes are the policy's
    worlds to the bit (``tests/test_ppo.py``)."""
    base = env.base_env
    return env if base.config.controller.needs_wind else base


def pd_evaluation(env: TransformedEnv, spec: RLEnvSpec, scenarios: TensorDictBase) -> dict[str, torch.Tensor]:
    """PD's per-episode results (:data:`PD_EVAL_KEYS`, rows in scenario order) on ``scenarios``
    beside a policy flying ``env``, built from ``spec``: read from the cache, else flown in
    :func:`pd_env` and kept there."""
    pd = pd_env(env)
    path = None if pd is env else entry_path(spec, pd.batch_size[0], scenarios)
    if path is not None:
        kept = _read(path, scenarios.batch_size[0])
        if kept is not None:
            return kept
    flown = fly_paired({"pd": (pd, None)}, scenarios)["pd"]
    result = {key: getattr(flown, key) for key in PD_EVAL_KEYS}
    if path is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            save_atomic(result, path)
        except OSError:  # a cache that cannot be written (read-only, full) only costs the next run PD's flights
            pass
    return result


def entry_path(spec: RLEnvSpec, batch: int, scenarios: TensorDictBase) -> Path:
    """The file that keeps PD's flights of ``scenarios`` in a ``batch``-row simulator built from
    ``spec`` (:func:`flight_key`), whether or not it exists yet."""
    return cache_dir() / "pd_flights" / f"{flight_key(spec, batch, scenarios)}.pt"


@functools.cache  # the source does not change under a running process (an edit means a new one)
def source_digest() -> str:
    """SHA-256 of the package's Python source: every file's path and bytes."""
    root = Path(__file__).resolve().parent.parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def flight_key(spec: RLEnvSpec, batch: int, scenarios: TensorDictBase) -> str:
    """The cache name of PD's flights of ``scenarios`` in a ``batch``-row simulator built from
    ``spec``: a digest of what those flights depend on (the module docstring lists it). The seed
    and the training episode sampler are left out: flights of given scenarios do not use them."""
    digest = hashlib.sha256(json.dumps({
        "source": source_digest(), "platform": platform_info(), "config": config_to_dict(spec.env_config),
        "compile_step": spec.compile_step, "device": str(spec.device), "batch": int(batch),
    }, sort_keys=True).encode())
    for key in sorted(scenarios.keys(True, True), key=str):
        value = scenarios.get(key).detach().cpu().contiguous()
        digest.update(f"{key}:{value.dtype}:{tuple(value.shape)}".encode())
        digest.update(value.numpy().tobytes())
    return digest.hexdigest()


def _read(path: Path, episodes: int) -> dict[str, torch.Tensor] | None:
    """The entry at ``path`` if it holds PD's results of ``episodes`` episodes; None when it is
    missing, unreadable or of another shape (the caller flies PD again and replaces it)."""
    try:
        kept = torch.load(path, weights_only=True)
    except Exception:  # missing, truncated, corrupt, or not a tensor file: nothing is trusted
        return None
    fits = (isinstance(kept, dict) and set(kept) == set(PD_EVAL_KEYS)
            and all(isinstance(v, torch.Tensor) and tuple(v.shape) == (episodes,) for v in kept.values())
            and torch.equal(kept["index"], torch.arange(episodes)))
    return kept if fits else None
