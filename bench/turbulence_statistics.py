"""Realised versus requested turbulence statistics, measured through ``Atmosphere.sample``.

A batch of sub-envs hovers at a fixed point while the frozen field is advected past it by the
mean wind (exactly the call the simulator makes every control step); the gust is projected on
each row's local mean-wind frame (along, across, up). Pooled over the batch it prints, per
layout and length scale:

* realised sigma / requested sigma per component (pooled over the three stability regimes,
  each row normalised by its own requested sigma);
* the longitudinal integral scale from a least-squares fit of the von Karman form
  ``Phi_u(k) = sigma^2 (2L/pi) / (1 + (1.339 L k)^2)^(5/6)`` to the pooled Welch spectrum;
* the log-log slope of that spectrum over 5 < k L < 40 (clipped below the layout's top mode);
* for ``paper_grid``, the variance its k range holds by the analytic spectrum at the bank's
  nearest length scale (the episode's cube is the bank's at that L).

    python bench/turbulence_statistics.py                 # the table in docs/atmosphere.md
    python bench/turbulence_statistics.py --n 128 --lengths 150 --layouts full

The field is sampled ``--per-l`` times per integral scale (the time step is chosen so the mean
wind moves the field by L / per-l per step) over ``--span-l`` integral scales per sub-env. The
default-layout field is scale-free in k L, so ``--env-dt`` also runs it at the simulator's
own 10 ms step with L = 5 m (the configuration of tests/test_atmosphere.py).

Point sampling aliases modes above the sampling Nyquist wavenumber (pi per sample spacing) back
into the measured spectrum. The default layout's top mode is k L = 800, so 50 samples per L
(Nyquist k L = 157) lifts the spectrum by a few % at k L = 20-40 and flattens the measured
inertial slope by ~0.03; ``--per-l 300`` (Nyquist k L = 942) removes that:

    python bench/turbulence_statistics.py --layouts full --lengths 150 --per-l 300 --span-l 41
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np
import torch
from scipy.integrate import quad
from scipy.optimize import curve_fit
from scipy.signal import welch

from quadwind_trl.config import TimingConfig, TurbulenceConfig, WindProfileConfig
from quadwind_trl.envs.atmosphere import Atmosphere, von_karman_energy, von_karman_longitudinal
from quadwind_trl.envs.scenarios import make_scenarios

ALTITUDE_M = 80.0
MEAN_WIND_M_S = 10.0  # at ALTITUDE_M
ALPHA = 0.2
INTENSITY = 0.1


def hover_record(layout: str, length: float, n: int, steps: int, dt: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Gust in the local frame ``[n, steps, 3]`` and each row's requested sigma ``[n, 3]``."""
    atm = Atmosphere(WindProfileConfig(), TurbulenceConfig(layout=layout))
    gen = torch.Generator().manual_seed(seed)
    stability = torch.arange(n) % 3
    sc = make_scenarios(
        n,
        traj_id="hover",
        altitude_m=ALTITUDE_M,  # the anisotropy frame is the mean-wind frame at this altitude
        wind_speed_ref_m_s=MEAN_WIND_M_S / (ALTITUDE_M / 10.0) ** ALPHA,
        shear_alpha=ALPHA,
        veer_deg_per_100m=6.0,
        wind_dir_deg=torch.rand(n, generator=gen) * 360.0,
        turb_intensity=INTENSITY,
        turb_length_scale_m=length,
        stability=stability,
        turb_seed=torch.arange(n) + seed * 100_000,
    )
    params, st = atm.init(sc)
    pos = torch.zeros(n, 3)
    pos[:, 2] = ALTITUDE_M
    out = torch.empty(n, steps, 3)
    with torch.no_grad():
        for k in range(steps):
            mean, total, st = atm.sample(params, st, pos, dt)
            gust = total - mean
            e = mean[:, :2] / mean[:, :2].norm(dim=-1, keepdim=True)
            out[:, k, 0] = e[:, 0] * gust[:, 0] + e[:, 1] * gust[:, 1]
            out[:, k, 1] = -e[:, 1] * gust[:, 0] + e[:, 0] * gust[:, 1]
            out[:, k, 2] = gust[:, 2]
    sigma_u = INTENSITY * MEAN_WIND_M_S * (ALTITUDE_M / 10.0) ** -TurbulenceConfig().intensity_altitude_exponent
    ratios = torch.tensor([(1.0, v, w) for v, w in TurbulenceConfig().stability_ratios], dtype=torch.float64)
    return out.double().numpy(), (sigma_u * ratios[stability]).numpy()


def analyse(gust: np.ndarray, sigma: np.ndarray, dx: float, length: float, k_top: float, segment_l: float) -> dict[str, float]:
    realised = np.sqrt((gust**2).mean(1))  # about the known zero mean, per row
    std_ratio = np.sqrt(((realised / sigma) ** 2).mean(0))
    along = gust[..., 0] / sigma[:, :1]
    nperseg = min(along.shape[1], int(round(segment_l * length / dx)))
    f, p = welch(along, fs=1.0 / dx, nperseg=nperseg, detrend=False, axis=-1)
    k, phi = 2 * np.pi * f[1:], p.mean(0)[1:] / (2 * np.pi)
    fit = k < min(30.0 / length, 0.8 * k_top)

    def log_model(k, log_l, s2):
        return np.log(von_karman_longitudinal(torch.from_numpy(k), math.exp(log_l), math.sqrt(s2)).numpy())

    try:
        (log_l, s2), _ = curve_fit(log_model, k[fit], np.log(phi[fit]), p0=(math.log(length), 0.8))
        l_fit, s2_fit = math.exp(log_l) / length, s2
    except RuntimeError:
        l_fit, s2_fit = float("nan"), float("nan")
    band = (k * length > 5.0) & (k * length < 40.0) & (k < 0.8 * k_top)
    slope = np.polyfit(np.log(k[band]), np.log(phi[band]), 1)[0] if band.sum() >= 3 else float("nan")
    # the same least-squares slope of the analytic form on the same spectral lines (the von Karman
    # spectrum is not yet a pure power law at k L = 5: its local slope there is -1.63)
    model = np.log(von_karman_longitudinal(torch.from_numpy(k[band]), length).numpy())
    model_slope = np.polyfit(np.log(k[band]), model, 1)[0] if band.sum() >= 3 else float("nan")
    return dict(su=std_ratio[0], sv=std_ratio[1], sw=std_ratio[2], l_fit=l_fit, s2_fit=s2_fit, slope=slope,
                model_slope=model_slope, band=(5.0, min(40.0, 0.8 * k_top * length)))  # fmt: skip


def cube_fraction(length: float) -> float:
    cfg = TurbulenceConfig(layout="paper_grid")
    length = min(cfg.cube_length_scales_m, key=lambda b: abs(math.log(b / length)))  # the bank's nearest
    k_min, k_max = 2 * math.pi / cfg.cube_size_m, math.pi / (cfg.cube_size_m / cfg.cube_points)
    energy = lambda k: von_karman_energy(torch.tensor(k, dtype=torch.float64), length).item()  # noqa: E731
    return quad(energy, k_min, k_max, limit=200)[0] / 1.5


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=384, help="sub-envs (a multiple of 3: one third per stability regime)")
    parser.add_argument("--lengths", type=float, nargs="+", default=[60.0, 150.0, 300.0])
    parser.add_argument("--layouts", nargs="+", default=["full", "paper_grid"])
    parser.add_argument("--per-l", type=int, default=50, help="samples per integral scale")
    parser.add_argument("--span-l", type=float, default=82.0, help="integral scales per sub-env")
    parser.add_argument("--segment-l", type=float, default=41.0, help="Welch segment length in integral scales")
    parser.add_argument("--env-dt", action="store_true", help="also the full layout at the 10 ms control step, L = 5 m")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    runs = [(layout, length, length / args.per_l / MEAN_WIND_M_S) for layout in args.layouts for length in args.lengths]
    if args.env_dt:
        runs.insert(0, ("full", 5.0, TimingConfig().control_dt_s))
    print("layout      L_m    dt_s    steps  sigma_u  sigma_v  sigma_w  L_fit/L  s2_fit  slope  (analytic, band kL)  sigma_predicted  seconds")
    for layout, length, dt in runs:
        dx = MEAN_WIND_M_S * dt
        steps = int(round(args.span_l * length / dx))
        start = time.perf_counter()
        gust, sigma = hover_record(layout, length, args.n, steps, dt, args.seed)
        k_top = (
            TurbulenceConfig().kappa_range[1] / length
            if layout == "full"
            else math.pi / (TurbulenceConfig().cube_size_m / TurbulenceConfig().cube_points)
        )
        r = analyse(gust, sigma, dx, length, k_top, args.segment_l)
        predicted = 1.0 if layout == "full" else cube_fraction(length)
        print(
            f"{layout:10s} {length:5.0f} {dt:7.4f} {steps:7d}  {r['su']:7.3f}  {r['sv']:7.3f}  {r['sw']:7.3f}  "
            f"{r['l_fit']:7.3f}  {r['s2_fit']:6.3f}  {r['slope']:6.3f} ({r['model_slope']:6.3f}, {r['band'][0]:.0f}-{r['band'][1]:.0f})"
            f"         {math.sqrt(predicted):6.3f}      {time.perf_counter() - start:5.1f}",
            flush=True,
        )
    print("sigma_*: realised / requested standard deviation (pooled over sub-envs and the three stability regimes);")
    print("s2_fit: the fitted Phi_u level / sigma_u^2; slope: log-log slope of the pooled spectrum, and of the analytic")
    print("  form on the same lines, over the band of k L shown (clipped below 0.8 x the layout's top wavenumber);")
    print("sigma_predicted: sqrt of the variance fraction the layout's k range holds by the analytic spectrum;")
    print(f"n={args.n} sub-envs, {args.span_l:g} L per sub-env, {args.per_l} samples per L, seed={args.seed}")


if __name__ == "__main__":
    main()
