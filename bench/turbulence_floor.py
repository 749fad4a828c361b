"""The flight-mean turbulence floor of the horizontal dataset's flights, per turbulence layout.

What a perfect air-velocity sensor would score against the mean-wind labels (the labels exclude
turbulence): the true total horizontal wind at every window's last sample, averaged over each
flight's windows, against the flight-averaged label, as ``evaluation.estimation.turbulence_floor``
computes it on a generated dataset (vector RMSE across flights, m/s); also the per-window floor
(the 60-sample window mean) and the instantaneous one.

The flights are the horizontal dataset's (``GenerationSpec(regime="horizontal")``: the LHS design
of ``regimes.DATASET_SEED``, 1000 cases x 5 trajectories), with windows cropped and strided as
the dataset's (``data.windows``). The air is sampled along each flight's *reference* path at the
10 Hz record instants, advecting the frozen field with the mean wind at the path's altitude over
each 0.1 s (PD tracks that path to about a metre, a few hundredths of the shortest length scale,
so no PD flight is needed: the floor is a property of the field along the path):

    python bench/turbulence_floor.py                          # both layouts, all 5000 flights
    python bench/turbulence_floor.py --cases 100 --layouts full

Prints the floors for all flights and for the test split's cases (the split the estimator is
scored on), per layout, and the time taken.
"""
from __future__ import annotations

import argparse
import time

import torch

from quadwind_trl.config import TrajectoryConfig, TurbulenceConfig, WindProfileConfig
from quadwind_trl.data.generate import GenerationSpec
from quadwind_trl.data.windows import STRIDE, WINDOW, crop_start, split_cases
from quadwind_trl.envs.atmosphere import Atmosphere
from quadwind_trl.envs.trajectories import TrajectoryLibrary
from quadwind_trl.regimes import DATASET_SEED

CONTROL_DT_S = 0.01
LOG_EVERY = 10  # control steps per 10 Hz record sample


def wind_along_paths(atm: Atmosphere, scenarios: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Total and mean horizontal wind ``[n, T, 2]`` at the 10 Hz record instants along the
    reference paths, and each flight's record length ``[n]``."""
    traj = TrajectoryLibrary(TrajectoryConfig(), CONTROL_DT_S)
    start, end = traj.schedule(scenarios["traj_id"], scenarios["altitude_m"])
    length = end // LOG_EVERY + 1
    n, t_len = start.shape[0], int(length.max())
    params, state = atm.init(scenarios)
    total = torch.zeros(n, t_len, 2)
    mean = torch.zeros(n, t_len, 2)
    with torch.no_grad():
        for i in range(t_len):
            step = torch.full_like(start, i * LOG_EVERY)
            pos = traj.reference(scenarios["traj_id"], step, start, scenarios["altitude_m"]).pos
            m, w, state = atm.sample(params, state, pos, LOG_EVERY * CONTROL_DT_S)
            total[:, i], mean[:, i] = w[:, :2], m[:, :2]
    return total, mean, length


def floors(total: torch.Tensor, mean: torch.Tensor, first: torch.Tensor, length: torch.Tensor) -> dict[str, torch.Tensor]:
    """Per-flight errors ``[n, 2]`` (flight mean) and per-window squared errors, windows as the dataset's."""
    t = torch.arange(total.shape[1])
    first_end = first + WINDOW - 1
    ends = (t >= first_end[:, None]) & (t < length[:, None]) & ((t - first_end[:, None]) % STRIDE["horizontal"] == 0)
    w = ends.to(total.dtype).unsqueeze(-1)
    count = w.sum(1)
    flight_err = (total * w).sum(1) / count - (mean * w).sum(1) / count
    csum = torch.cat((torch.zeros_like(total[:, :1]), total.cumsum(1)), 1)
    window_mean = (csum[:, WINDOW:] - csum[:, :-WINDOW]) / WINDOW  # trailing mean ending at index WINDOW-1+j
    pad = torch.zeros_like(total[:, : WINDOW - 1])
    window_err2 = ((torch.cat((pad, window_mean), 1) - mean) ** 2).sum(-1)[ends]
    inst_err2 = ((total - mean) ** 2).sum(-1)[ends]
    return {"flight": flight_err, "window2": window_err2, "inst2": inst_err2, "ends": ends}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cases", type=int, default=1000)
    parser.add_argument("--layouts", nargs="+", default=["full", "paper_grid"])
    parser.add_argument("--chunk", type=int, default=1000, help="flights per batch")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    spec = GenerationSpec(regime="horizontal", cases=args.cases, seed=DATASET_SEED["horizontal"])
    scenarios = spec.scenarios()
    test_cases = split_cases(scenarios["case_id"])["test"]
    is_test = torch.isin(scenarios["case_id"], test_cases)
    first = crop_start(scenarios["traj_id"], scenarios["altitude_m"], TrajectoryConfig())
    print(f"{scenarios.shape[0]} horizontal flights ({args.cases} cases x {len(spec.trajectories)}), "
          f"{int(is_test.sum())} in the test split")  # fmt: skip
    print("layout       flights  flight-mean floor  6 s window-mean floor  instantaneous  seconds")
    for layout in args.layouts:
        begin = time.perf_counter()
        atm = Atmosphere(WindProfileConfig(), TurbulenceConfig(layout=layout))
        parts = []
        for rows in torch.arange(scenarios.shape[0]).split(args.chunk):
            sc = {k: v[rows] for k, v in scenarios.items()}
            total, mean, length = wind_along_paths(atm, sc)
            f = floors(total, mean, first[rows], length)
            window_flight = f["ends"].nonzero()[:, 0]  # each window's flight (row in this chunk)
            parts.append((rows, f["flight"], f["window2"], f["inst2"], rows[window_flight]))
        flight = torch.cat([p[1] for p in parts])
        window2, inst2, window_row = (torch.cat([p[i] for p in parts]) for i in (2, 3, 4))
        seconds = time.perf_counter() - begin
        for name, sel in (("all", torch.ones_like(is_test)), ("test", is_test)):
            wsel = sel[window_row]
            print(
                f"{layout:11s} {name:5s} {int(sel.sum()):5d}  {flight[sel].pow(2).sum(-1).mean().sqrt():15.3f} m/s"
                f"  {window2[wsel].mean().sqrt():19.3f} m/s  {inst2[wsel].mean().sqrt():11.3f} m/s  {seconds:7.1f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
