"""Scalar wind-estimation metrics (paper, Section "Metrics") over estimates and labels ``[W, 2]``
(north, east) in m/s, one row per window: what training validates on and what the evaluation
reports (:mod:`quadwind_trl.evaluation.estimation` has the definitions, breakdowns and sweeps).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from .loss import wind_angle


def to_float64(x: Tensor) -> Tensor:
    return torch.as_tensor(x).to(torch.float64)


def vector_rmse(pred: Tensor, true: Tensor) -> float:
    """``sqrt(mean |pred - true|^2)`` over rows of ``[W, 2]``."""
    d = to_float64(pred) - to_float64(true)
    return float((d * d).sum(-1).mean().sqrt())


def component_rmse(pred: Tensor, true: Tensor) -> tuple[float, float]:
    """RMSE of the north and of the east component."""
    d = to_float64(pred) - to_float64(true)
    r = (d * d).mean(0).sqrt()
    return float(r[0]), float(r[1])


def direction_errors_deg(pred: Tensor, true: Tensor) -> Tensor:
    """Unsigned angle between estimate and label, degrees, per row."""
    return torch.rad2deg(wind_angle(to_float64(pred), to_float64(true)))


def pearson(a: Tensor, b: Tensor) -> float:
    """Pearson correlation of two 1-D samples (nan if either is constant)."""
    a, b = to_float64(a).flatten(), to_float64(b).flatten()
    a, b = a - a.mean(), b - b.mean()
    den = (a.square().sum() * b.square().sum()).sqrt()
    return float((a * b).sum() / den) if den > 0 else float("nan")


def flight_means(values: Tensor, flight: Tensor) -> tuple[Tensor, Tensor]:
    """``(ids, means)``: the mean of ``values`` ``[W, ...]`` over each distinct ``flight`` id."""
    ids, inverse = torch.unique(flight, return_inverse=True)
    v = to_float64(values).reshape(values.shape[0], -1)
    sums = torch.zeros(ids.numel(), v.shape[1], dtype=torch.float64).index_add_(0, inverse, v)
    counts = torch.bincount(inverse, minlength=ids.numel()).to(torch.float64)
    return ids, (sums / counts[:, None]).reshape(ids.numel(), *values.shape[1:])


def per_flight_vector_rmse(pred: Tensor, true: Tensor, flight: Tensor) -> float:
    """Vector RMSE across flights of (flight-averaged estimate - flight-averaged label)."""
    _, p = flight_means(pred, flight)
    _, t = flight_means(true, flight)
    return vector_rmse(p, t)


@dataclass(frozen=True)
class ConstantReference:
    """The best constant predictors of a set: its mean wind vector and its mean speed."""

    vector: tuple[float, float]
    speed: float

    @classmethod
    def fit(cls, true: Tensor) -> "ConstantReference":
        t = to_float64(true)
        m = t.mean(0)
        return cls((float(m[0]), float(m[1])), float(t.norm(dim=-1).mean()))


def skill(rmse_model: float, rmse_ref: float) -> float:
    """``1 - rmse_model / rmse_ref`` (nan when the reference is exact)."""
    return 1.0 - rmse_model / rmse_ref if rmse_ref > 0 else float("nan")


def least_squares_slope(x: Tensor, y: Tensor) -> float:
    """Slope of the least-squares line ``y = a + b x`` (nan if ``x`` is constant)."""
    x, y = to_float64(x).flatten(), to_float64(y).flatten()
    xc = x - x.mean()
    den = xc.square().sum()
    return float((xc * (y - y.mean())).sum() / den) if den > 0 else float("nan")


def estimation_metrics(
    pred: Tensor,
    true: Tensor,
    flight: Tensor | None = None,
    altitude: Tensor | None = None,
    reference: ConstantReference | None = None,
) -> dict[str, float]:
    """All scalar metrics of windows ``pred``/``true`` ``[W, 2]`` (m/s).

    ``flight`` ``[W]`` (ids) adds ``per_flight_vector_rmse``; ``altitude`` ``[W]`` (m) adds the
    altitude-speed slopes; ``reference`` (default: fitted on ``true``) sets the skill baselines.
    """
    pred, true = to_float64(pred), to_float64(true)
    w = pred.shape[0]
    if w == 0:
        return {"n_windows": 0}
    ref = reference or ConstantReference.fit(true)
    rn, re = component_rmse(pred, true)
    sp, st = pred.norm(dim=-1), true.norm(dim=-1)
    ref_vec = torch.tensor(ref.vector, dtype=torch.float64).expand_as(true)
    speed_rmse = float((sp - st).square().mean().sqrt())
    out = {
        "n_windows": w,
        "per_window_vector_rmse": vector_rmse(pred, true),
        "component_rmse_n": rn,
        "component_rmse_e": re,
        "component_mean_rmse": 0.5 * (rn + re),
        "direction_mae_deg": float(direction_errors_deg(pred, true).mean()),
        "corr_n": pearson(pred[:, 0], true[:, 0]),
        "corr_e": pearson(pred[:, 1], true[:, 1]),
        "speed_rmse": speed_rmse,
        "speed_bias": float((sp - st).mean()),
        "mean_true_speed": float(st.mean()),
        "reference_vector_rmse": vector_rmse(ref_vec, true),
        "reference_speed_rmse": float((st - ref.speed).square().mean().sqrt()),
    }
    out["vector_skill"] = skill(out["per_window_vector_rmse"], out["reference_vector_rmse"])
    out["speed_skill"] = skill(speed_rmse, out["reference_speed_rmse"])
    if flight is not None:
        out["n_flights"] = int(torch.unique(flight).numel())
        out["per_flight_vector_rmse"] = per_flight_vector_rmse(pred, true, flight)
    if altitude is not None:
        out["altitude_speed_slope_pred"] = least_squares_slope(altitude, sp)
        out["altitude_speed_slope_true"] = least_squares_slope(altitude, st)
    return out
