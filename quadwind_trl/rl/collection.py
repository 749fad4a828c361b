"""Where a PPO run steps its rows (``PPOConfig.collector``): here, or in Ray actors on a cluster.

``"local"``: the training env in this process, or its rows split over ``collect_workers`` local
processes. ``"ray"``: the same row split over ``num_collectors`` Ray actors
(:class:`~quadwind_trl.envs.ray_rows.RayRowsEnv`), placed by Ray on any node of the cluster at
``ray_address``. Either way TorchRL's single-process ``Collector`` runs here with the policy, and
so do the transforms that pool every row (the running observation normalisation, then clipping,
zeroed inputs, episode sums): a worker, local or remote, holds only the row-wise transforms
(simulator, episode control, wind estimate, observation). The normalisation statistics therefore
live in one place, this process's ``VecNormV2``, and update on every step from every row as in
one process; checkpoints and ``policy.pt`` save them from there. The rows fly the episodes of the
one-process env, and a batch collected through Ray actors equals the batch of the same number of
local workers bit for bit, so the layout is a speed setting a resume may change.
"""
from __future__ import annotations

import contextlib
from typing import ContextManager

import torch
from torchrl.envs import TransformedEnv

from ..envs.ray_rows import RayRowsEnv
from ..ray_cluster import check_address, import_ray, joined
from .config import PPOConfig

# what a missing Ray's error names: the option that needs it, and what to do instead
NEEDS_RAY = {"option": "--collector ray",
             "alternative": "leave out --collector ray, --num-collectors and --address to collect on this machine "
                            "(--collect-workers)"}


def env_layout(cfg: PPOConfig) -> dict:
    """``build_env`` keywords of the training env: its collection workers and where they run."""
    if cfg.collector == "ray":
        return {"workers": cfg.num_collectors, "workers_on": "ray"}
    return {"workers": cfg.collect_workers}


def check_device(cfg: PPOConfig, device: str) -> None:
    """Refuse Ray collection of rows on another device than the CPU (``RLEnvSpec.device``): the
    actors ask Ray for CPUs only, and their tensors travel through Ray on the CPU."""
    if cfg.collector == "ray" and torch.device(device).type != "cpu":
        raise ValueError(f"PPOConfig.collector='ray' (--collector ray) flies the rows on the CPU; got --device {device}: "
                         "collect with --collector local there")


def check_ray(cfg: PPOConfig) -> None:
    """For a run that collects on Ray: refuse at once a missing Ray or an ``--address`` where no
    head node answers (:class:`~quadwind_trl.ray_cluster.RayUnavailable`, naming the options)."""
    if cfg.collector == "ray":
        import_ray(**NEEDS_RAY)
        check_address(cfg.ray_address)


def connected(cfg: PPOConfig) -> ContextManager[str | None]:
    """Inside: connected to the run's Ray cluster (a local instance of ``num_collectors`` CPUs when
    ``ray_address`` is None) unless it collects locally; a connection this process made before is
    used and left open. Yields a line saying where, or None."""
    if cfg.collector != "ray":
        return contextlib.nullcontext()
    return joined(cfg.ray_address, cfg.num_collectors, **NEEDS_RAY)


def describe(cfg: PPOConfig, env: TransformedEnv | None = None) -> dict:
    """The manifest's record of how the run collects (this session's layout; with the training
    ``env``, the hosts its Ray actors run on)."""
    if cfg.collector != "ray":
        return {"collector": "local", "workers": cfg.collect_workers}
    rows = None if env is None else env.base_env
    nodes = rows.nodes if isinstance(rows, RayRowsEnv) else []
    return {"collector": "ray", "num_collectors": cfg.num_collectors, "rows_per_collector": cfg.num_envs // cfg.num_collectors,
            "ray_address": cfg.ray_address, "nodes": nodes}
