"""Fly a list of episode specs through an env (PD alone, or any TorchRL policy) and collect
per-episode tracking RMSE and the 10 Hz flight record.

The same runner serves dataset generation (PD), calibration and the paired evaluation (PD,
wind-blind and wind-aware policies on identical scenarios): the physics is replayed from the
scenarios, so which controller flies changes nothing but the controller.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterator, Sequence

import torch
from tensordict import TensorDict, TensorDictBase
from torch import Tensor
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp
from tqdm.auto import tqdm

from ..config import EnvConfig
from ..keys import MEAS_KEY, RESIDUAL_ENTRY
from .quad_env import QuadWindEnv
from .scenarios import validate_scenarios
from .simulator import trajectory_library

NestedKey = str | tuple[str, ...]
Policy = Callable[[TensorDictBase], TensorDictBase]
AUTO_PROGRESS_DELAY_S = 3.0

# the 10 Hz record's entries by default (the applied residual's entry is named by what it acts on:
# default_log_keys)
DEFAULT_LOG_KEYS: tuple[NestedKey, ...] = (
    MEAS_KEY,
    "cmd_wrench",
    "pd_wrench",
    RESIDUAL_ENTRY["wrench"],
    "ref_pos",
    "tilt_cmd",
    "tilt_saturated",
    "step",
    ("truth", "pos"),
    ("truth", "vel"),
    ("truth", "wind"),
    ("truth", "mean_wind"),
)


def default_log_keys(config: EnvConfig) -> tuple[NestedKey, ...]:
    """:data:`DEFAULT_LOG_KEYS` for an env of ``config``: its residual's entry (``ff_wrench`` or ``ff_acc``)."""
    ff = RESIDUAL_ENTRY["wrench"]
    return tuple(RESIDUAL_ENTRY[config.residual.acts_on] if key == ff else key for key in DEFAULT_LOG_KEYS)


@dataclass
class FlightResults:
    """Per-episode results of one batch of flights (rows follow ``index``)."""

    index: Tensor  # [n] row of each flight in the scenario batch given to the runner
    rmse_xy: Tensor  # [n] horizontal position RMSE over the scored part of the flight (m)
    rmse_z: Tensor  # [n] vertical position RMSE (m)
    crashed: Tensor  # [n] bool: the episode terminated early
    log: TensorDict  # [n, T] 10 Hz record of ``log_keys`` plus a bool "valid" entry
    # [n] RMSE of the navigation solution the PD flies on against the true position, on the same
    # steps: the part of the tracking error the vehicle cannot perceive (0 with true-state feedback).
    # None only where results are rebuilt from stored RMSEs (the trainer's cached PD evaluation).
    nav_rmse_xy: Tensor | None = None
    nav_rmse_z: Tensor | None = None

    @property
    def rmse(self) -> Tensor:
        """Combined position RMSE ``sqrt(rmse_xy^2 + rmse_z^2)``."""
        return torch.sqrt(self.rmse_xy**2 + self.rmse_z**2)


def scored_samples(log: TensorDictBase, pattern_start: Tensor) -> Tensor:
    """``[n, T]`` bool: the samples of a flight record (:attr:`FlightResults.log`, with ``"step"``)
    taken at steps the RMSE scores: after the pattern starts (``pattern_start`` ``[n]``), while the
    episode runs. With one decision per log tick (the RL regimes) they are exactly the scored steps."""
    return log["valid"] & (log["step"].squeeze(-1) > pattern_start.unsqueeze(-1))


def _base(env: EnvBase) -> QuadWindEnv:
    base = getattr(env, "base_env", env)
    if not isinstance(base, QuadWindEnv):
        raise TypeError(f"the runner flies QuadWindEnv (possibly transformed), got {type(base).__name__}")
    return base


def flight_order(config: EnvConfig, scenarios: TensorDictBase, device: torch.device | str = "cpu") -> tuple[Tensor, Tensor]:
    """``(order, planned)``: the scenario rows in the order the runner flies them in an env of
    ``config`` (longest first, ties in scenario order; batch ``k`` of an env of ``N`` rows is
    ``order[k N : (k + 1) N]``) and each scenario's planned control steps."""
    log_every = config.timing.log_every_control_steps
    traj = trajectory_library(config, torch.device(device))
    pattern_start, end_step = traj.schedule(scenarios["traj_id"].to(device), scenarios["altitude_m"].to(device))
    start = torch.where(scenarios["start_step"].to(device) < 0, pattern_start, scenarios["start_step"].to(device))
    if bool((start % log_every).any()):
        raise ValueError(f"scenario start_step must be a multiple of the {log_every}-step log interval")
    planned = (end_step - start).cpu()
    return torch.argsort(planned, descending=True, stable=True), planned


def iter_flights(
    env: EnvBase,
    scenarios: TensorDictBase,
    policy: Policy | None = None,
    log_keys: Sequence[NestedKey] | None = None,
    progress: bool | None = None,
    skip: Tensor | None = None,
    chunks: range | None = None,
) -> Iterator[FlightResults]:
    """Fly ``scenarios`` (batch ``[M]``) in chunks of the env's batch size, longest first.

    The position error is scored at every env step (every control step, or every
    ``TimingConfig.hold_control_steps``-th when the env holds actions) after the pattern starts (for horizontal
    flights: after the climb) up to the end of the episode; the flight record holds every 10th
    control step from the episode start (``log_keys``; None: :func:`default_log_keys`).
    ``policy=None`` flies the PD baseline (zero action).
    ``progress``: a tqdm bar (``None``, the default: shown once the flights have taken
    ``AUTO_PROGRESS_DELAY_S``; ``True`` at once; ``False`` never).
    ``skip`` (bool ``[M]``): flights already flown; a chunk of only those is not flown again (the
    chunks depend only on the scenarios and the batch size, so a resumed run meets the same ones).
    ``chunks``: fly only the chunks of these indices (in flying order), each exactly as in a full
    run: a batch's flights replay bit for bit only within the same batch.
    """
    base = _base(env)
    log_keys = default_log_keys(base.config) if log_keys is None else log_keys
    validate_scenarios(scenarios)
    n_env = base.batch_size[0]
    log_every = base.config.timing.log_every_control_steps
    order, planned = flight_order(base.config, scenarios, base.device)
    batches = order.split(n_env)
    # progress=None: a bar only once the work has taken a few seconds (quick calls stay quiet)
    bar = tqdm(total=int(planned.sum()), unit="step", unit_scale=True, disable=progress is False, desc="flights",
               delay=0.0 if progress else AUTO_PROGRESS_DELAY_S)
    for k, chunk in enumerate(batches):
        if (skip is not None and bool(skip[chunk].all())) or (chunks is not None and k not in chunks):
            bar.update(int(planned[chunk].sum()))
            continue
        rows = torch.cat((chunk, chunk[-1:].expand(n_env - chunk.numel()))) if chunk.numel() < n_env else chunk
        yield _fly_chunk(env, base, scenarios[rows.to(scenarios.device)], policy, log_keys, int(planned[chunk].max()), log_every, chunk)
        bar.update(int(planned[chunk].sum()))
    bar.close()



def fly(env: EnvBase, scenarios: TensorDictBase, policy: Policy | None = None, **options) -> FlightResults:
    """All flights of :func:`iter_flights` (``options``: its ``log_keys``, ``progress``, ``skip``,
    ``chunks``), in the order of ``scenarios`` (with ``skip`` or ``chunks``, only the flights flown:
    ``index`` holds their rows); records are padded to the longest flight (``log["valid"]`` marks
    real samples)."""
    parts = list(iter_flights(env, scenarios, policy, **options))
    length = max(p.log.batch_size[1] for p in parts)
    logs = []
    for p in parts:
        pad = length - p.log.batch_size[1]
        if pad:
            tail = p.log[:, -1:].expand(p.log.batch_size[0], pad).clone()
            tail["valid"] = torch.zeros_like(tail["valid"])
            logs.append(torch.cat((p.log, tail), 1))
        else:
            logs.append(p.log)
    index = torch.cat([p.index for p in parts])
    inverse = torch.argsort(index)
    return FlightResults(
        index=index[inverse],
        rmse_xy=torch.cat([p.rmse_xy for p in parts])[inverse],
        rmse_z=torch.cat([p.rmse_z for p in parts])[inverse],
        crashed=torch.cat([p.crashed for p in parts])[inverse],
        nav_rmse_xy=torch.cat([p.nav_rmse_xy for p in parts])[inverse],
        nav_rmse_z=torch.cat([p.nav_rmse_z for p in parts])[inverse],
        log=torch.cat(logs)[inverse.to(logs[0].device)],
    )


@torch.no_grad()
def _fly_chunk(
    env: EnvBase,
    base: QuadWindEnv,
    scenarios: TensorDictBase,
    policy,
    log_keys: Sequence[NestedKey],
    num_steps: int,
    log_every: int,
    index: Tensor,
) -> FlightResults:
    n = base.batch_size[0]
    dev = base.device
    td = env.reset(scenario=scenarios.to(dev))
    pattern_start = base.sim_state("pattern_start")
    num_logs = num_steps // log_every + 1
    records = [td.select(*log_keys)]
    valid = [torch.ones(n, dtype=torch.bool, device=dev)]
    active = torch.ones(n, dtype=torch.bool, device=dev)
    sq_xy = torch.zeros(n, device=dev)
    sq_z = torch.zeros(n, device=dev)
    nav_sq_xy = torch.zeros(n, device=dev)
    nav_sq_z = torch.zeros(n, device=dev)
    count = torch.zeros(n, device=dev)
    crashed = torch.zeros(n, dtype=torch.bool, device=dev)
    zero_action = base.action_spec.zero()
    timing = base.config.timing
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for i in range(1, -(-num_steps // timing.hold_control_steps) + 1):
            if policy is None:
                td.set("action", zero_action)
            else:
                td = policy(td)
            td = env.step(td)
            nxt = td.get("next")
            err = nxt.get(("truth", "pos")) - nxt.get("ref_pos")
            scored = active & (nxt.get("step").squeeze(-1) > pattern_start)
            sq_xy += torch.where(scored, err[..., :2].pow(2).sum(-1), 0.0)
            sq_z += torch.where(scored, err[..., 2].pow(2), 0.0)
            nav_err = nxt.get("nav_pos") - nxt.get(("truth", "pos"))
            nav_sq_xy += torch.where(scored, nav_err[..., :2].pow(2).sum(-1), 0.0)
            nav_sq_z += torch.where(scored, nav_err[..., 2].pow(2), 0.0)
            count += scored
            crashed |= active & nxt.get("terminated").squeeze(-1)
            if i % timing.decisions_per_log == 0:
                records.append(nxt.select(*log_keys))
                valid.append(active.clone())
            active = active & ~nxt.get("done").squeeze(-1)
            td = step_mdp(td, keep_other=True)
    log = torch.stack(records[:num_logs], 1)[: index.numel()]
    log["valid"] = torch.stack(valid[:num_logs], 1)[: index.numel()]
    assert log.batch_size[1] == num_logs
    k = index.numel()
    denom = count[:k].clamp_min(1)
    return FlightResults(
        index=index,
        rmse_xy=(sq_xy[:k] / denom).sqrt().cpu(),
        rmse_z=(sq_z[:k] / denom).sqrt().cpu(),
        crashed=crashed[:k].cpu(),
        nav_rmse_xy=(nav_sq_xy[:k] / denom).sqrt().cpu(),
        nav_rmse_z=(nav_sq_z[:k] / denom).sqrt().cpu(),
        log=log.cpu(),
    )
