"""One validation layer for what users hand the library: episode specs (scenarios), configs,
actions and checkpoint files.

Every check fails early with a ``ValueError`` (``TypeError`` for a wrong Python type) whose
message names the field, the value and what is allowed. The boundaries call it: scenarios when
they are made (:func:`~quadwind_trl.envs.scenarios.make_scenarios`) and when an episode batch is
reset or flown (:func:`~quadwind_trl.envs.scenarios.validate_scenarios` hands :func:`check_rows`
the scenario schema with the registered trajectories' ids), configs in ``EnvConfig.validate``,
the action shape in ``QuadWindEnv._step`` (a Python-level shape comparison: no host sync in the
step's hot path), and the kind of a checkpoint in the loaders.

This module sits below everything it checks: it imports nothing from the package, so what it
checks against that lives elsewhere (the trajectory registry) is handed in by the caller.
"""
from __future__ import annotations

import math
import types
import typing
from dataclasses import dataclass, fields, is_dataclass
from pathlib import Path
from typing import Literal, get_args, get_origin

import torch
from tensordict import TensorDictBase


@dataclass(frozen=True)
class Range:
    """Closed interval ``[low, high]`` allowed for a field, and the physical reason for it."""

    low: float
    high: float
    why: str
    integer: bool = False

    def describe(self) -> str:
        return f"[{self.low:g}, {self.high:g}] ({self.why})"


# --- scenarios -----------------------------------------------------------------------------------

# Ranges a simulated episode can mean something physically. The paper's designs use far narrower
# ones (docs/simulator.md); these only keep out values the models are not made for.
SCENARIO_RANGES: dict[str, Range] = {
    # above ground, up to the top of the atmospheric boundary layer the wind model describes
    "altitude_m": Range(0.0, 3000.0, "m above ground: ground level to the top of the boundary layer"),
    # the 10 m mean wind of a storm; the paper flies 1-15 m/s and caps the wind at altitude at 20
    "wind_speed_ref_m_s": Range(0.0, 40.0, "m/s mean wind at the reference height; a speed is never negative"),
    "wind_dir_deg": Range(-360.0, 720.0, "deg clockwise from north (one turn either way)"),
    # sigma_u / U: 0.05-0.4 in the atmosphere; at >= 1 gusts exceed the mean and the frozen-field
    # (Taylor) turbulence model stops describing the flow
    "turb_intensity": Range(0.0, 1.0, "sigma_u / U, a fraction"),
    # power-law exponent: about 0.1 over open water to 0.4 over cities; 0 is no shear
    "shear_alpha": Range(0.0, 1.0, "power-law shear exponent"),
    "veer_deg_per_100m": Range(-90.0, 90.0, "deg of wind turning per 100 m of height"),
    # the von Karman integral length scale: tens of metres near the ground to ~1 km aloft
    "turb_length_scale_m": Range(1.0, 5000.0, "m, the von Karman integral length scale, positive"),
    "turb_seed": Range(0, 2**62, "a non-negative integer", integer=True),
    "sensor_seed": Range(0, 2**62, "a non-negative integer", integer=True),
    "start_step": Range(-1, 2**31, "a control step; -1 starts at the pattern", integer=True),
}


def as_field_tensor(name: str, value, dtype: torch.dtype, batch: int, device) -> torch.Tensor:
    """``value`` (a scalar, or one value per episode) as a ``[batch]`` tensor of ``dtype``."""
    if isinstance(value, str):
        raise TypeError(f"{name}={value!r}: expected a number or one number per episode, got a string")
    try:
        t = torch.as_tensor(value, device=device)
    except (TypeError, ValueError, RuntimeError) as err:
        raise TypeError(f"{name}={value!r}: expected a number or a sequence of {batch} numbers ({err})") from None
    if t.dtype == torch.bool or t.is_complex():
        raise TypeError(f"{name}={value!r}: expected a real number, got dtype {t.dtype}")
    if t.ndim == 0:
        t = t.expand(batch)
    elif t.ndim != 1 or t.numel() != batch:
        raise ValueError(f"{name}: got shape {tuple(t.shape)}, expected a scalar or {batch} values (one per episode)")
    if not dtype.is_floating_point and t.is_floating_point():
        if not bool(torch.isfinite(t).all()) or bool((t != t.round()).any()):
            raise ValueError(f"{name}={_show(t)}: expected integers")
    return t.to(dtype).clone()


def _show(t: torch.Tensor) -> str:
    """A short rendering of a value: float32 digits beyond ~7 are noise (1.7 is not 1.70000005)."""
    if t.numel() > 8:
        return f"tensor of {t.numel()} values"
    values = [f"{v:.7g}" if isinstance(v, float) else str(v) for v in t.reshape(-1).tolist()]
    return values[0] if t.ndim == 0 else "[" + ", ".join(values) + "]"


def check_rows(what: str, rows: TensorDictBase, schema: dict[str, tuple[torch.dtype, Range]]) -> TensorDictBase:
    """Check the fields of a batch ``[N]`` against ``schema`` (field -> dtype, allowed range):
    the dtype's kind (integer or floating), finiteness and range of every row; returns ``rows``.

    One host sync per call: it runs where episodes are made or reset with a given spec, never
    inside a step."""
    if rows.batch_dims != 1:
        raise ValueError(f"{what}: expected a batch [N], got batch size {list(rows.batch_size)}")
    checks = []
    for name, (dtype, allowed) in schema.items():
        value = rows.get(name)
        if value.dtype.is_floating_point != dtype.is_floating_point:
            raise TypeError(f"{what} field {name}: dtype {value.dtype}, expected {dtype}")
        checks.append(_bad_mask(value, allowed))
    # one sync for the whole batch: which fields have a bad row
    bad = torch.stack([m.any() for m in checks]).tolist()
    for (name, (_, allowed)), is_bad, mask in zip(schema.items(), bad, checks):
        if is_bad:
            value = rows.get(name)
            row = int(mask.nonzero()[0, 0])
            finite = "finite values in " if value.is_floating_point() else ""
            raise ValueError(f"{what} field {name}={_show(value[row])} (row {row}) is not allowed; "
                             f"allowed: {finite}{allowed.describe()}")
    return rows


def _bad_mask(value: torch.Tensor, r: Range) -> torch.Tensor:
    bad = (value < r.low) | (value > r.high)
    return bad | ~torch.isfinite(value) if value.is_floating_point() else bad


# --- configs -------------------------------------------------------------------------------------

# "ClassName.field" -> allowed range. Fields not listed get the type and finiteness checks, and
# fields named as magnitudes (``_is_magnitude``) must not be negative.
CONFIG_RANGES: dict[str, Range] = {
    "VehicleConfig.arm_length_m": Range(0.01, 5.0, "m, hub to rotor axis"),
    "VehicleConfig.thrust_coeff": Range(1e-9, 1e-2, "N / (rad/s)^2, positive"),
    "VehicleConfig.rotor_speed_max_rad_s": Range(1.0, 1e5, "rad/s, positive"),
    "VehicleConfig.air_density_kg_m3": Range(0.1, 2.0, "kg/m^3, sea level 1.225"),
    "ControllerConfig.kp_pos": Range(0.0, 1e3, "1/s^2, a stabilising gain is non-negative"),
    "ControllerConfig.kd_pos": Range(0.0, 1e3, "1/s"),
    "ControllerConfig.k_att": Range(0.0, 1e4, "N m / rad"),
    "ControllerConfig.k_rate": Range(0.0, 1e4, "N m s / rad"),
    "ResidualConfig.action_scale": Range(0.0, 1e3, "N and N m per unit action"),
    "ResidualConfig.acceleration_scale_m_s2": Range(0.0, 100.0, "m/s^2 per unit action, positive"),
    "ResidualConfig.acceleration_slew_m_s2_per_step": Range(0.0, 100.0, "m/s^2 per control step, positive"),
    "TimingConfig.physics_dt_s": Range(1e-5, 0.1, "s, positive"),
    "TimingConfig.control_substeps": Range(1, 1000, "physics substeps per control step", integer=True),
    "TimingConfig.log_every_control_steps": Range(1, 1000, "control steps per log sample", integer=True),
    "WindProfileConfig.reference_height_m": Range(0.1, 1000.0, "m, positive: the power law divides by it"),
    "WindProfileConfig.max_horizontal_wind_m_s": Range(0.0, 100.0, "m/s"),
    "RewardConfig.crash_tilt_deg": Range(1.0, 180.0, "deg"),
    # inf is the unbounded limit of the Gauss-Markov bias: a random walk (the legacy_walk preset)
    "SensorChannelConfig.bias_corr_time_s": Range(1e-3, math.inf, "s, positive; inf makes the bias a random walk"),
}
# a field whose name ends in one of these units, or names one of these quantities, is a magnitude
# (a duration, a rate, a mass, an area, a spread, a size) and is never negative
MAGNITUDE_UNITS = ("_s", "_hz", "_kg", "_m2", "_kg_m2", "_kg_m3")
MAGNITUDE_WORDS = ("std", "duration", "radius", "length", "legs", "spacing", "speed")


def _is_number(value) -> bool:
    """A Python ``int`` or ``float``, not a ``bool`` (configs and designs go into JSON manifests)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _is_magnitude(name: str) -> bool:
    return name.endswith(MAGNITUDE_UNITS) or any(w in name for w in MAGNITUDE_WORDS)


def validate_config(cfg, owner: str | None = None) -> None:
    """Type, shape, finiteness and range of every field of a (nested) config dataclass."""
    owner = owner or type(cfg).__name__
    hints = typing.get_type_hints(type(cfg))
    for f in fields(cfg):
        value = getattr(cfg, f.name)
        label = f"{owner}.{f.name}"
        if is_dataclass(value):
            validate_config(value, label)
            continue
        _check_value(label, f"{type(cfg).__name__}.{f.name}", value, hints[f.name], f.name)


def _check_value(label: str, key: str, value, hint, name: str) -> None:
    origin = get_origin(hint)
    if origin is Literal:
        if value not in get_args(hint):
            raise ValueError(f"{label}={value!r}; allowed: {', '.join(repr(a) for a in get_args(hint))}")
        return
    if origin is tuple:
        args = get_args(hint)
        if not isinstance(value, tuple):
            raise TypeError(f"{label}={value!r}: expected a tuple")
        if len(args) == 2 and args[1] is Ellipsis:
            items = [(v, args[0]) for v in value]
        elif len(value) != len(args):
            raise ValueError(f"{label}={value!r}: expected {len(args)} values, got {len(value)}")
        else:
            items = list(zip(value, args))
        for v, h in items:
            _check_value(label, key, v, h, name)
        return
    if hint is bool:
        if not isinstance(value, bool):
            raise TypeError(f"{label}={value!r}: expected True or False")
        return
    # an optional number: typing.Optional[float] and float | None (types.UnionType) alike
    if hint in (int, float) or (origin in (typing.Union, types.UnionType) and set(get_args(hint)) <= {int, float, type(None)}):
        if value is None and type(None) in get_args(hint):
            return
        if not _is_number(value):
            raise TypeError(f"{label}={value!r}: expected a number")
        if hint is int and not isinstance(value, int):
            raise TypeError(f"{label}={value!r}: expected an integer")
        r = CONFIG_RANGES.get(key)
        if not math.isfinite(value) and not (r is not None and value == r.high == math.inf):
            raise ValueError(f"{label}={value!r} must be finite")
        if r is not None and not r.low <= value <= r.high:
            raise ValueError(f"{label}={value!r} is outside the allowed range {r.describe()}")
        if r is None and value < 0 and _is_magnitude(name):
            raise ValueError(f"{label}={value!r} must be >= 0 (a magnitude)")


# --- actions -------------------------------------------------------------------------------------


def check_action(action: torch.Tensor | None, batch: int, dim: int) -> None:
    """The action's shape must be ``[batch, dim]``: a shape comparison only (no host sync)."""
    if action is None:
        raise ValueError(f"action is missing: the step needs an 'action' entry of shape ({batch}, {dim})")
    if tuple(action.shape) != (batch, dim):
        raise ValueError(
            f"action has shape {tuple(action.shape)}, expected ({batch}, {dim}): one residual in [-1, 1]^{dim} per "
            "sub-env (ResidualConfig.acts_on: thrust and three torques on the wrench, forward, left and up on the "
            "acceleration)"
        )


# --- checkpoints ---------------------------------------------------------------------------------

CheckpointKind = Literal["policy", "estimator"]
KIND_DESCRIPTION = {
    "policy": "a PPO policy (load it with quadwind_trl.rl.policy.load_policy)",
    "estimator": "a wind-estimator bundle (load it with quadwind_trl.estimator.load_estimator)",
}


def checkpoint_kind(payload: dict) -> str:
    """``payload["kind"]``, or for checkpoints written before kinds existed, inferred from their
    entries."""
    if "kind" in payload:
        return payload["kind"]
    if "ppo_config" in payload and "policy" in payload:
        return "policy"
    if "schema" in payload and "state_dict" in payload:
        return "estimator"
    return "unknown"


def load_checkpoint(path: str | Path, kind: CheckpointKind, device: torch.device | str = "cpu") -> dict:
    """``torch.load`` a checkpoint and check that it is of ``kind``; the error says what it is."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint file at {path}")
    try:
        payload = torch.load(path, map_location=device, weights_only=True)
    except Exception as err:  # pickle, zip and weights-only errors alike: not a checkpoint of ours
        raise ValueError(f"{path} is not a quadwind_trl checkpoint ({type(err).__name__}: {str(err)[:200]})") from None
    if not isinstance(payload, dict):
        raise ValueError(f"{path} is not a quadwind_trl checkpoint (it holds a {type(payload).__name__})")
    found = checkpoint_kind(payload)
    if found != kind:
        what = KIND_DESCRIPTION.get(found, "not a quadwind_trl checkpoint (no policy or estimator entries)")
        raise ValueError(f"{path} is {what}, not {KIND_DESCRIPTION[kind].split(' (')[0]}")
    return payload


# RegimeRanges field -> the scenario field its values become
_RANGE_FIELDS = {
    "wind_speed_m_s": "wind_speed_ref_m_s",
    "wind_dir_deg": "wind_dir_deg",
    "intensity": "turb_intensity",
    "shear_alpha": "shear_alpha",
    "veer_deg_per_100m": "veer_deg_per_100m",
    "length_scale_m": "turb_length_scale_m",
    "altitude_m": "altitude_m",
}


def validate_ranges(ranges) -> None:
    """A Latin-hypercube design (``RegimeRanges``): each ``(low, high)`` finite, ordered and
    inside the range its scenario field allows."""
    owner = type(ranges).__name__
    for name, field in _RANGE_FIELDS.items():
        bounds = getattr(ranges, name)
        if bounds is None and name == "altitude_m":
            continue
        if not (isinstance(bounds, (tuple, list)) and len(bounds) == 2):
            raise ValueError(f"{owner}.{name}={bounds!r}: expected a (low, high) pair")
        if not all(map(_is_number, bounds)):
            raise TypeError(f"{owner}.{name}={bounds!r}: expected a (low, high) pair of numbers")
        low, high = bounds
        r = SCENARIO_RANGES[field]
        if not (math.isfinite(low) and math.isfinite(high) and r.low <= low <= high <= r.high):
            raise ValueError(f"{owner}.{name}={bounds!r}: expected low <= high within {r.describe()}")
    for name in ("top_altitude_m", "wind_ceiling_m_s", "reference_height_m"):
        value = getattr(ranges, name)
        if not _is_number(value):
            raise TypeError(f"{owner}.{name}={value!r}: expected a number")
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{owner}.{name}={value!r} must be finite and > 0")
