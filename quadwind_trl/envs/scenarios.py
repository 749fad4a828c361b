"""Episode specs ("scenarios") and the Latin-hypercube wind-regime designs.

A scenario fully defines one episode: running it gives the same physics whatever the
controller, the batch size or its row in the batch (exact replay). It is a
:class:`~tensordict.TensorDict` of batch ``[N]`` with the fields of ``SCENARIO_FIELDS``.
"""
from __future__ import annotations

import operator
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase

from ..validation import SCENARIO_RANGES, Range, as_field_tensor, check_rows, validate_ranges
from .counter_rng import hash_bits, hash_uniform
from .trajectories import HORIZONTAL, trajectory_id, trajectory_ids, trajectory_names

# the atmospheric stability regimes a scenario's ``stability`` field indexes (the checks name them;
# TurbulenceConfig.stability_ratios holds one pair per regime, in this order)
STABILITY_NAMES = ("neutral", "stable", "convective")

# name -> (dtype, default)
SCENARIO_FIELDS: dict[str, tuple[torch.dtype, float | int]] = {
    "traj_id": (torch.int64, 0),  # a registered pattern's id (envs/trajectories); make_scenarios also takes names
    "altitude_m": (torch.float32, 100.0),  # flight altitude of a horizontal pattern
    "wind_speed_ref_m_s": (torch.float32, 0.0),  # U_mean at z_ref
    "wind_dir_deg": (torch.float32, 0.0),  # direction the wind blows from, clockwise from north
    "turb_intensity": (torch.float32, 0.0),
    "shear_alpha": (torch.float32, 0.14),
    "veer_deg_per_100m": (torch.float32, 0.0),
    "turb_length_scale_m": (torch.float32, 150.0),
    "stability": (torch.int64, 0),  # index into STABILITY_NAMES
    "turb_seed": (torch.int64, 0),
    "sensor_seed": (torch.int64, 0),
    "start_step": (torch.int64, 0),  # control step to start at: 0 on the ground, -1 at the pattern start
}


def make_scenarios(batch: int, device: torch.device | str | None = None, *, check: bool = True, **fields) -> TensorDict:
    """A scenario batch with defaults for every field not given (scalars broadcast).

    ``traj_id`` may also be given by name (a string, or a sequence of strings). Every field is
    checked (``quadwind_trl.validation``): a bad value fails here, naming the field and the
    allowed range or names. ``check=False`` skips the value checks (one host sync) for batches
    made from already checked values, such as the samplers' draws within checked ranges.
    """
    try:
        batch = operator.index(batch)  # ints of any kind (Python, numpy, 0-d integer tensors), not floats
    except TypeError:
        raise TypeError(f"batch={batch!r}: expected a positive integer (the number of episodes)") from None
    if batch < 1:
        raise ValueError(f"batch={batch}: expected a positive integer (the number of episodes)")
    unknown = set(fields) - set(SCENARIO_FIELDS)
    if unknown:
        raise KeyError(f"unknown scenario fields {sorted(unknown)}; allowed: {sorted(SCENARIO_FIELDS)}")
    traj = fields.get("traj_id")
    if isinstance(traj, str):
        fields["traj_id"] = trajectory_id(traj)
    elif isinstance(traj, (list, tuple)) and any(isinstance(t, str) for t in traj):
        fields["traj_id"] = [trajectory_id(t) if isinstance(t, str) else t for t in traj]
    out = {name: as_field_tensor(name, fields.get(name, default), dtype, batch, device)
           for name, (dtype, default) in SCENARIO_FIELDS.items()}
    td = TensorDict(out, batch_size=[batch], device=device)
    return validate_scenarios(td) if check else td


def validate_scenarios(scenarios: TensorDictBase) -> TensorDictBase:
    """Check every field of a scenario batch (type, shape, finiteness, range); returns it. The
    ids a ``traj_id`` may take are those registered now (user patterns included)."""
    missing = [k for k in SCENARIO_FIELDS if k not in scenarios.keys()]
    if missing:
        raise ValueError(f"scenario is missing fields {missing}; make it with make_scenarios(...)")
    allowed = {**SCENARIO_RANGES, "traj_id": _id_range("registered trajectories", trajectory_names()),
               "stability": _id_range("stability regimes", STABILITY_NAMES)}
    return check_rows("scenario", scenarios, {name: (dtype, allowed[name]) for name, (dtype, _) in SCENARIO_FIELDS.items()})


def _id_range(what: str, names: tuple[str, ...]) -> Range:
    """The ids of ``names`` (an id is a position), each named in the message."""
    return Range(0, len(names) - 1, f"{what}: " + ", ".join(f"{i} {n}" for i, n in enumerate(names)), integer=True)


@dataclass(frozen=True)
class RegimeRanges:
    """Ranges of a Latin-hypercube wind design (ours where the paper gives none: docs/simulator.md).

    ``altitude_m=None`` makes a vertical design (6 dimensions, wind bounded at ``top_altitude_m``);
    a range makes a horizontal one (7 dimensions, wind bounded at each flight's own altitude).
    """

    wind_speed_m_s: tuple[float, float] = (1.0, 20.0)
    wind_dir_deg: tuple[float, float] = (0.0, 360.0)
    intensity: tuple[float, float] = (0.08, 0.25)  # paper (datasets)
    shear_alpha: tuple[float, float] = (0.08, 0.25)
    veer_deg_per_100m: tuple[float, float] = (3.0, 8.0)  # paper
    length_scale_m: tuple[float, float] = (60.0, 300.0)
    altitude_m: tuple[float, float] | None = (80.0, 550.0)  # paper (horizontal)
    top_altitude_m: float = 600.0  # paper (vertical)
    wind_ceiling_m_s: float = 20.0  # paper: the mean wind at altitude stays below this
    reference_height_m: float = 10.0

    def __post_init__(self):
        validate_ranges(self)

    @property
    def dims(self) -> int:
        return 6 if self.altitude_m is None else 7


def latin_hypercube(n: int, dims: int, seed: int) -> torch.Tensor:
    """``[n, dims]`` float64 points in [0, 1): each dimension has exactly one point per bin
    ``[i/n, (i+1)/n)``; bins are paired across dimensions by independent random permutations."""
    gen = torch.Generator().manual_seed(seed)
    perms = torch.stack([torch.randperm(n, generator=gen) for _ in range(dims)], -1).to(torch.float64)
    jitter = torch.rand(n, dims, generator=gen, dtype=torch.float64)
    return (perms + jitter) / n


def wind_ceiling_bound(ranges: RegimeRanges, alpha: torch.Tensor, altitude: torch.Tensor) -> torch.Tensor:
    """Largest U_ref whose mean wind at ``altitude`` stays within the ceiling."""
    # exp(alpha log(.)) rather than ``**``: torch's CPU pow rounds differently in a kernel's
    # vectorised body and its scalar tail, so a row of random_scenarios would depend on the
    # batch size (tests/test_scenarios.py)
    factor = torch.exp(alpha * torch.log(altitude.clamp_min(ranges.reference_height_m) / ranges.reference_height_m))
    return torch.minimum(torch.full_like(alpha, ranges.wind_speed_m_s[1]), ranges.wind_ceiling_m_s / factor)


def regimes_from_unit(u: torch.Tensor, ranges: RegimeRanges, *, check: bool = False, **fields) -> TensorDict:
    """Map unit-cube points ``[n, >= dims]`` to wind regimes; ``fields`` adds other scenario fields
    or replaces drawn ones (a factorial sweep sets the wind speed and intensity itself).

    ``check=False`` (the samplers): every drawn value lies within ``ranges``, checked when they
    were made; pass ``check=True`` when ``fields`` brings values from elsewhere."""
    n = u.shape[0]

    def scale(col: int, bounds: tuple[float, float]) -> torch.Tensor:
        return bounds[0] + u[:, col] * (bounds[1] - bounds[0])

    alpha = scale(3, ranges.shear_alpha)
    if ranges.altitude_m is None:
        altitude = torch.full((n,), ranges.top_altitude_m, dtype=u.dtype, device=u.device)
    else:
        altitude = scale(6, ranges.altitude_m)
    lower = ranges.wind_speed_m_s[0]
    upper = wind_ceiling_bound(ranges, alpha, altitude)
    drawn = dict(
        wind_speed_ref_m_s=lower + u[:, 0] * (upper - lower).clamp_min(0.0),
        wind_dir_deg=scale(1, ranges.wind_dir_deg),
        turb_intensity=scale(2, ranges.intensity),
        shear_alpha=alpha,
        veer_deg_per_100m=scale(4, ranges.veer_deg_per_100m),
        turb_length_scale_m=scale(5, ranges.length_scale_m),
        altitude_m=altitude,
    )
    return make_scenarios(n, device=u.device, check=check, **{**drawn, **fields})


def sample_regimes(n: int, ranges: RegimeRanges, seed: int) -> TensorDict:
    """``n`` wind cases by Latin hypercube: wind fields, altitude (horizontal designs), the
    stability regime cycled neutral/stable/convective by case index, and per-case seeds."""
    index = torch.arange(n)
    seeds = hash_bits(torch.full((n,), seed, dtype=torch.int64), index, stream=301, num=2) & 0x7FFFFFFF
    return regimes_from_unit(
        latin_hypercube(n, ranges.dims, seed), ranges, stability=index % 3, turb_seed=seeds[:, 0], sensor_seed=seeds[:, 1]
    )


def cross_with_trajectories(cases: TensorDict, trajectories: tuple[str, ...] = HORIZONTAL) -> TensorDict:
    """Every wind case flown on every trajectory: ``len(cases) * len(trajectories)`` scenarios,
    case-major, with a ``case_id`` entry for splitting by wind case."""
    n, t = cases.batch_size[0], len(trajectories)
    out = cases.unsqueeze(1).expand(n, t).clone().reshape(n * t)
    ids = trajectory_ids(trajectories, cases.device)
    out["traj_id"] = ids.repeat(n)
    out["case_id"] = torch.arange(n, device=cases.device).repeat_interleave(t)
    return out


def random_scenarios(key: torch.Tensor, counter: torch.Tensor, ranges: RegimeRanges, traj_ids: torch.Tensor) -> TensorDict:
    """Independent uniform draws (not a hypercube) of one scenario per row, a pure function of
    ``(key, counter)``: what a training env uses to give every sub-env a fresh episode on reset."""
    u = hash_uniform(key, counter, stream=302, num=ranges.dims + 1).to(torch.float64)
    bits = hash_bits(key, counter, stream=303, num=3) & 0x7FFFFFFF
    pick = (u[:, ranges.dims] * traj_ids.numel()).long().clamp_max(traj_ids.numel() - 1)
    return regimes_from_unit(
        u, ranges, traj_id=traj_ids[pick], stability=bits[:, 2] % 3, turb_seed=bits[:, 0], sensor_seed=bits[:, 1]
    )
