"""One evaluation of a trained wind estimator on a dataset: per-flight estimate sequences of the
validation, held-out test and (optionally) unseen-design flights, the EMA tau sweep on validation,
and raw vs filtered metrics (``recipes/evaluate_estimator.py`` writes them out; the tables are
:mod:`.estimation_tables`, the figures :mod:`.estimation_figures`)."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Sequence

import torch
from torch import Tensor

from ..envs.trajectories import trajectory_names
from ..estimator.base import WindEstimator
from ..estimator.ema import EMAConfig
from ..estimator.training import EstimatorData, split_flights
from .estimation import FlightSequences, best_tau, ema_sweep, evaluate_sequences, per_flight_aggregation, predict_flights


@dataclass
class EstimationRun:
    """The numbers (``results``, JSON-ready) and the sequences the figures are drawn from."""

    regime: str
    paper_tau_s: float  # the paper's deployed EMA tau, reported beside ours
    results: dict
    sweep: dict[float, dict]  # validation metrics per swept tau (0: raw)
    tau_best: float  # the validation-best tau: the one the PPO recipes deploy (rl.envs.validated_tau_s)
    taus: list[float]  # the nonzero taus evaluated on test (and unseen): the paper's and the best
    test: FlightSequences
    test_filtered: dict[float, Tensor]  # tau -> EMA-filtered test estimates
    unseen: FlightSequences | None = None
    unseen_filtered: dict[float, Tensor] = field(default_factory=dict)


def flight_sequences(estimator: WindEstimator, ed: EstimatorData, flights: Tensor, stride: int, batch: int,
                     desc: str) -> FlightSequences:
    """The estimates along each of ``flights`` (dataset rows) every ``stride`` samples."""
    wd, rec = ed.windows, ed.data["record"]
    if estimator.window != wd.window:
        raise ValueError(f"the estimator reads {estimator.window}-sample windows, the dataset's windows are {wd.window} samples")
    pos = torch.as_tensor(rec["pos"])
    wind = torch.as_tensor(rec["wind"])
    t0 = time.perf_counter()
    seq = predict_flights(
        estimator.predict, wd.features, wd.labels, pos[..., 2], flights, wd.crop, wd.length,
        ed.data["traj_id"], ed.data["case_id"], wind=torch.stack((wind[..., 1], wind[..., 0]), -1),
        window=wd.window, stride=stride, batch_size=batch, record_dt_s=ed.manifest["record_dt_s"], progress=True,
    )  # fmt: skip
    n = int(seq.mask.sum())
    dt = time.perf_counter() - t0
    print(f"{desc}: {flights.numel()} flights, {n:,} windows estimated in {dt:.1f} s ({n / max(dt, 1e-9):.0f} windows/s)", flush=True)
    return seq


def _filtered(seq: FlightSequences, taus: Sequence[float]) -> dict[float, Tensor]:
    return {tau: seq.filtered(EMAConfig(tau_s=tau, dt_s=seq.dt_s)) for tau in taus}


def run_estimation(
    estimator: WindEstimator,
    ed: EstimatorData,
    results: dict,
    *,
    unseen: EstimatorData | None = None,
    stride: int = 1,
    batch: int = 1024,
    taus: Sequence[float],
    paper_tau_s: float,
) -> EstimationRun:
    """Evaluate ``estimator`` on ``ed``'s validation (tau sweep) and test flights and on every
    flight of ``unseen``; the metrics are added to ``results`` (whose entries stay first)."""
    regime = ed.regime
    names = list(trajectory_names())
    val = flight_sequences(estimator, ed, split_flights(ed.windows, "val"), stride, batch, "validation")
    sweep = ema_sweep(val, taus)
    tau_best = best_tau(sweep)
    results["val_ema_sweep"] = {str(k): v for k, v in sweep.items()}
    results["val_best_tau_s"] = tau_best
    # how each flight's estimates become one per-flight estimate: raw and at the validation-best tau
    filters = {0.0: None, **({tau_best: val.filtered(EMAConfig(tau_s=tau_best, dt_s=val.dt_s))} if tau_best else {})}
    results["val_flight_aggregation"] = {str(t): per_flight_aggregation(val, f) for t, f in filters.items()}
    del val

    test = flight_sequences(estimator, ed, split_flights(ed.windows, "test"), stride, batch, "test")
    results["test"] = evaluate_sequences(test, names)
    filtered_taus = sorted({paper_tau_s, tau_best} - {0.0})
    test_f = _filtered(test, filtered_taus)
    results["test_ema"] = {str(tau): evaluate_sequences(test, names, pred=f)["summary"] for tau, f in test_f.items()}
    results["test_flight_aggregation"] = {
        str(t): per_flight_aggregation(test, test_f[t] if t else None) for t in ([0.0, tau_best] if tau_best else [0.0])
    }
    run = EstimationRun(regime, paper_tau_s, results, sweep, tau_best, filtered_taus, test, test_f)

    if unseen is not None:
        if unseen.info["seed"] == ed.info["seed"]:
            print(f"WARNING: --unseen-data has the same LHS seed ({unseen.info['seed']}) as --data: not an independent design", flush=True)
        flights = torch.unique(torch.cat([unseen.windows.tables[s][:, 0] for s in ("train", "val", "test")]))
        run.unseen = flight_sequences(estimator, unseen, flights, stride, batch, "unseen")
        results["unseen"] = evaluate_sequences(run.unseen, names)
        results["unseen_data"] = unseen.info
        run.unseen_filtered = _filtered(run.unseen, filtered_taus)
        results["unseen_ema"] = {
            str(tau): evaluate_sequences(run.unseen, names, pred=f)["summary"] for tau, f in run.unseen_filtered.items()
        }
    return run
