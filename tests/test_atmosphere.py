"""The atmosphere against hand-derived values and the analytic von Karman statistics.

Statistics are pooled over a batch of sub-envs (each its own rotation of the mode skeleton,
its own phases), sampled along straight lines many integral scales long. The main spectral
test goes through ``Atmosphere.sample`` exactly as the simulator calls it: a vehicle holding
its position while the frozen field is advected past it by the mean wind at the env's 100 Hz
control step, so a missing or doubled time-step factor anywhere in the advection or in the
amplitudes shows up as a wrong variance, a white spectrum or a wrong length scale.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.integrate import quad
from scipy.optimize import curve_fit
from scipy.signal import welch
from tensordict import TensorDict

from quadwind_trl.config import TimingConfig, TurbulenceConfig, WindProfileConfig
from quadwind_trl.envs.atmosphere import Atmosphere, von_karman_energy, von_karman_longitudinal
from quadwind_trl.envs.counter_rng import hash_normal
from quadwind_trl.envs.rotations import quat_to_rotmat
from quadwind_trl.envs.scenarios import RegimeRanges, make_scenarios, sample_regimes

CONTROL_DT = TimingConfig().control_dt_s  # the step the simulator advects the field with
NEUTRAL, STABLE, CONVECTIVE = 0, 1, 2


def scenario(n: int, **fields) -> dict[str, torch.Tensor]:
    return dict(make_scenarios(n, **fields).items())


# --- mean profile: power law, veer, direction convention, cap ---------------------------------


def test_profile_constants_are_the_papers():
    assert WindProfileConfig().reference_height_m == 10.0
    assert WindProfileConfig().max_horizontal_wind_m_s == 20.0


def test_mean_wind_power_law_veer_and_direction_by_hand():
    atm = Atmosphere(WindProfileConfig(), TurbulenceConfig(enabled=False))
    z = torch.tensor([0.0, 5.0, 10.0, 100.0, 210.0, 600.0])
    params, _ = atm.init(
        scenario(6, wind_speed_ref_m_s=8.0, shear_alpha=0.2, wind_dir_deg=30.0, veer_deg_per_100m=5.0)
    )
    mean = atm.mean_wind(params, z)
    # U(z) = 8 (max(z, 10) / 10)^0.2 ; from(z) = 30 deg + 5 deg per 100 m above z_ref
    speed = [8.0, 8.0, 8.0, 8.0 * 10**0.2, 8.0 * 21**0.2, 8.0 * 60**0.2]
    from_deg = [30.0, 30.0, 30.0, 34.5, 40.0, 59.5]
    expected = torch.tensor(
        [[-u * math.sin(math.radians(d)), -u * math.cos(math.radians(d)), 0.0] for u, d in zip(speed, from_deg)]
    )
    torch.testing.assert_close(mean, expected, rtol=2e-6, atol=2e-6)
    assert abs(speed[3] - 12.6791) < 1e-4  # 8 * 10^0.2, by hand


@pytest.mark.parametrize(
    "from_deg, east, north",
    [(0.0, 0.0, -1.0), (90.0, -1.0, 0.0), (180.0, 0.0, 1.0), (270.0, 1.0, 0.0), (225.0, 0.5**0.5, 0.5**0.5)],
)
def test_direction_is_meteorological_from_clockwise_from_north(from_deg, east, north):
    """A northerly (from 0 deg) blows towards the south: ENU (0, -U); an easterly towards the
    west: (-U, 0); a south-westerly (225 deg) towards the north-east."""
    atm = Atmosphere(WindProfileConfig(), TurbulenceConfig(enabled=False))
    params, _ = atm.init(scenario(1, wind_speed_ref_m_s=6.0, wind_dir_deg=from_deg, veer_deg_per_100m=0.0))
    mean = atm.mean_wind(params, torch.tensor([50.0]))
    u50 = 6.0 * 5.0**0.14
    torch.testing.assert_close(mean, torch.tensor([[east * u50, north * u50, 0.0]]), rtol=1e-6, atol=1e-5)


def test_veer_turns_clockwise_with_height_and_is_linear():
    atm = Atmosphere(WindProfileConfig(), TurbulenceConfig(enabled=False))
    z = torch.linspace(10.0, 600.0, 60)
    params, _ = atm.init(scenario(60, wind_speed_ref_m_s=5.0, wind_dir_deg=350.0, veer_deg_per_100m=7.0))
    mean = atm.mean_wind(params, z).double()
    # the "from" direction is atan2(-east, -north), clockwise from north
    from_deg = torch.rad2deg(torch.atan2(-mean[:, 0], -mean[:, 1]))
    unwrapped = torch.from_numpy(np.rad2deg(np.unwrap(np.deg2rad(from_deg.numpy()))))
    torch.testing.assert_close(unwrapped - unwrapped[0], 7.0 * (z.double() - 10.0) / 100.0, rtol=0, atol=1e-3)


def test_mean_wind_is_capped_at_20_m_s_keeping_its_direction():
    atm = Atmosphere(WindProfileConfig(), TurbulenceConfig(enabled=False))
    params, _ = atm.init(scenario(2, wind_speed_ref_m_s=15.0, shear_alpha=0.25, wind_dir_deg=120.0))
    mean = atm.mean_wind(params, torch.tensor([400.0, 10.0]))  # 15 * 40^0.25 = 37.7 m/s uncapped
    assert abs(mean[0, :2].norm().item() - 20.0) < 1e-5
    assert abs(mean[1, :2].norm().item() - 15.0) < 1e-5
    torch.testing.assert_close(mean[0, :2] / 20.0, mean[1, :2] / 15.0, rtol=1e-6, atol=1e-6)


def test_cap_clips_the_mean_or_the_total_and_disabled_turbulence_gives_the_mean():
    n = 512
    pos = torch.zeros(n, 3)
    pos[:, 2] = 10.0
    cases = scenario(n, wind_speed_ref_m_s=18.0, turb_intensity=0.25, turb_length_scale_m=50.0, turb_seed=torch.arange(n))
    # default: the cap clips the mean profile only; gusts ride on top of it
    atm = Atmosphere(WindProfileConfig(), TurbulenceConfig())
    mean, total, _ = atm.sample(*atm.init(cases), pos, CONTROL_DT)
    assert (mean[:, :2].norm(dim=-1) <= 20.0 + 1e-4).all()
    assert (total[:, :2].norm(dim=-1) > 20.5).any()
    # "total": mean plus gust is capped too
    capped = Atmosphere(WindProfileConfig(cap_applies_to="total"), TurbulenceConfig())
    _, total_c, _ = capped.sample(*capped.init(cases), pos, CONTROL_DT)
    horiz = total_c[:, :2].norm(dim=-1)
    assert (horiz <= 20.0 + 1e-4).all() and (horiz > 19.99).any()  # the cap binds for some rows
    calm = Atmosphere(WindProfileConfig(), TurbulenceConfig(enabled=False))
    mean0, total0, _ = calm.sample(*calm.init(scenario(n, wind_speed_ref_m_s=18.0)), pos, CONTROL_DT)
    assert torch.equal(mean0, total0) and torch.equal(mean0, mean)


# --- turbulence: deterministic structure ------------------------------------------------------


def test_sigma_scales_with_local_mean_speed_altitude_and_stability():
    """sigma_u = I U(z) (z / z_ref)^-0.05; sigma_v, sigma_w by the configured regime ratios."""
    cfg = TurbulenceConfig()
    atm = Atmosphere(WindProfileConfig(), cfg)
    params, _ = atm.init(
        scenario(3, wind_speed_ref_m_s=7.0, shear_alpha=0.15, turb_intensity=0.2, stability=torch.tensor([0, 1, 2]))
    )
    z = torch.tensor([120.0, 120.0, 5.0])
    sigma = atm.turbulence_sigma(params, atm.mean_wind(params, z), z)
    su = [0.2 * 7.0 * 12**0.15 * 12**-0.05, 0.2 * 7.0 * 12**0.15 * 12**-0.05, 0.2 * 7.0]
    ratios = [(1.0,) + tuple(r) for r in cfg.stability_ratios]
    expected = torch.tensor([[s * r for r in ratio] for s, ratio in zip(su, ratios)])
    torch.testing.assert_close(sigma, expected, rtol=2e-6, atol=1e-6)


def test_gust_is_the_stretched_mode_sum_built_by_hand():
    """total - mean = sigma_u(z) F D R v(R^T D^-1 F^T (x - offset)), with v the skeleton's mode sum,
    F the mean-wind frame (along, across, up) at the episode's anchor altitude (a horizontal
    pattern's altitude; half a vertical design's altitude), D = diag(1, r_v, r_w), R the
    episode's rotation; built here in float64 from the skeleton, with non-default ratios."""
    cfg = TurbulenceConfig(stability_ratios=((0.5, 0.25), (1.5, 0.1), (0.9, 2.0)))
    atm = Atmosphere(WindProfileConfig(), cfg)
    n = 3
    params, st = atm.init(
        scenario(n, traj_id=["racetrack_h", "spiral_ascent", "hover"], altitude_m=torch.tensor([300.0, 600.0, 40.0]),
                 wind_speed_ref_m_s=6.0, wind_dir_deg=200.0, veer_deg_per_100m=8.0, shear_alpha=0.1,
                 turb_intensity=0.15, turb_length_scale_m=80.0, stability=torch.tensor([0, 1, 2]),
                 turb_seed=torch.tensor([3, 4, 5]))
    )  # fmt: skip
    st["air_offset"] = torch.tensor([[40.0, -7.0, 0.0], [0.0, 0.0, 0.0], [-300.0, 11.0, 0.0]])
    pos = torch.tensor([[5.0, 6.0, 310.0], [-20.0, 3.0, 60.0], [0.0, 0.0, 10.0]])
    mean, total, _ = atm.sample(params, st, pos, CONTROL_DT)
    anchor = torch.tensor([300.0, 300.0, 40.0], dtype=torch.float64)
    wind_from = torch.deg2rad(200.0 + 8.0 * (anchor - 10.0) / 100.0)
    along = torch.stack((-torch.sin(wind_from), -torch.cos(wind_from), torch.zeros(n, dtype=torch.float64)), -1)
    up = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(n, 3)
    frame = torch.stack((along, torch.linalg.cross(up, along), up), -1)  # columns; across 90 deg left of along
    ratios = torch.tensor([[1.0, 0.5, 0.25], [1.0, 1.5, 0.1], [1.0, 0.9, 2.0]], dtype=torch.float64)
    seed = torch.tensor([3, 4, 5])
    q = hash_normal(seed, 0, 101, 4).double()
    rot = quat_to_rotmat(q / q.norm(dim=-1, keepdim=True))
    x = (pos - st["air_offset"]).double()
    y = rot.transpose(-1, -2) @ ((frame.transpose(-1, -2) @ x.unsqueeze(-1)).squeeze(-1) / ratios).unsqueeze(-1)
    k = atm.wavevector.double() / 80.0  # [M, 3] rad/m
    theta = (k @ y).squeeze(-1) + params["phase"].double()  # [n, M]
    v = (torch.cos(theta) * params["amplitude"].double()) @ atm.velocity_dir.double()  # [n, 3]
    gust_unit = (frame @ (ratios * (rot @ v.unsqueeze(-1)).squeeze(-1)).unsqueeze(-1)).squeeze(-1)
    z = pos[:, 2].double()
    sigma_u = 0.15 * 6.0 * (z / 10.0) ** 0.1 * (z / 10.0) ** -0.05
    torch.testing.assert_close((total - mean).double(), sigma_u.unsqueeze(-1) * gust_unit, rtol=1e-4, atol=2e-5)


def test_frozen_field_is_advected_with_the_integrated_mean_wind():
    """A vehicle drifting with the mean wind sees a constant gust (Taylor's frozen field); a
    hovering one sees the field at ``pos - sum(mean dt)``; halving dt and doubling the steps
    reaches the same field at the same time."""
    atm = Atmosphere(WindProfileConfig(), TurbulenceConfig())
    n = 16
    params, st0 = atm.init(
        scenario(n, wind_speed_ref_m_s=9.0, wind_dir_deg=250.0, turb_intensity=0.2, turb_length_scale_m=60.0,
                 turb_seed=torch.arange(n) + 11)
    )  # fmt: skip
    start = torch.zeros(n, 3)
    start[:, 2] = 10.0
    mean0 = atm.mean_wind(params, start[:, 2])

    st, pos, gusts = st0, start.clone(), []
    for _ in range(200):  # 2 s drifting with the wind (18 m, 0.3 L)
        mean, total, st = atm.sample(params, st, pos, CONTROL_DT)
        gusts.append(total - mean)
        pos = pos + CONTROL_DT * mean
    gusts = torch.stack(gusts)
    assert (gusts - gusts[0]).abs().max() < 2e-3 * gusts.abs().max()

    def hover(dt: float, steps: int):
        state = st0
        for _ in range(steps):
            mean, total, state = atm.sample(params, state, start, dt)
        return total - mean, state

    # the gust returned by a call is the field at the offset *before* that call's advection:
    # 299 steps of dt and 598 steps of dt / 2 reach the same offset, for the 300th and 599th calls
    g1, s1 = hover(CONTROL_DT, 300)
    g2, s2 = hover(CONTROL_DT / 2, 599)
    torch.testing.assert_close(s1["air_offset"], 300 * CONTROL_DT * mean0, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(s2["air_offset"], 599 * CONTROL_DT / 2 * mean0, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(g2, g1, rtol=1e-3, atol=1e-3)
    # the gust applied over the last step is the field at pos minus the offset before that step
    frozen = atm.unit_gust(params, start - 299 * CONTROL_DT * mean0)
    expected = atm.turbulence_sigma(params, mean0, start[:, 2])[:, :1] * frozen
    torch.testing.assert_close(g1, expected, rtol=1e-3, atol=1e-3)
    assert g1.std() > 0.1  # it is not trivially zero


def to_local(v: torch.Tensor, mean: torch.Tensor) -> torch.Tensor:
    """ENU vectors ``v`` in the frame (along, across, up) of the horizontal mean wind."""
    e = mean[:, :2] / mean[:, :2].norm(dim=-1, keepdim=True)
    return torch.stack((e[:, 0] * v[:, 0] + e[:, 1] * v[:, 1], -e[:, 1] * v[:, 0] + e[:, 0] * v[:, 1], v[:, 2]), -1)


def test_full_layout_is_scale_free_in_k_L():
    """The default layout depends on position only through x / L: the field of length scale
    2L at 2x equals the field of scale L at x (so statistics at any L test every L)."""
    atm = Atmosphere(WindProfileConfig(), TurbulenceConfig())
    n = 64
    seeds = torch.arange(n) + 500
    a, _ = atm.init(scenario(n, turb_length_scale_m=40.0, turb_seed=seeds))
    b, _ = atm.init(scenario(n, turb_length_scale_m=80.0, turb_seed=seeds))
    x = torch.randn(n, 3, generator=torch.Generator().manual_seed(1)) * 100.0
    torch.testing.assert_close(atm.unit_gust(b, 2 * x), atm.unit_gust(a, x), rtol=2e-4, atol=2e-4)


def test_modes_are_transverse_and_full_layout_has_unit_variance_per_component():
    atm = Atmosphere(WindProfileConfig(), TurbulenceConfig())
    # the wavevector is the evaluation's own (kappa_m d_m): transverse to the mode velocity, and
    # its length the log-spaced dimensionless wavenumber
    k = atm.wavevector.double()
    dot = (k / k.norm(dim=-1, keepdim=True) * atm.velocity_dir.double()).sum(-1)
    assert dot.abs().max() < 1e-6
    lo, hi = TurbulenceConfig().kappa_range
    kappa = torch.logspace(math.log10(lo), math.log10(hi), 300, dtype=torch.float64)
    torch.testing.assert_close(k.norm(dim=-1), kappa, rtol=1e-6, atol=0)
    torch.testing.assert_close(atm.velocity_dir.norm(dim=-1), torch.ones(300), rtol=0, atol=1e-6)
    # sum over modes of a^2 <cos^2> |d|^2 = 3 (all three components), i.e. 1 per component
    assert abs(0.5 * (atm.shared_amplitude.double() ** 2).sum().item() / 3.0 - 1.0) < 1e-5


def _float64(atm: Atmosphere, parts: tuple[TensorDict, TensorDict]) -> tuple[TensorDict, TensorDict]:
    """The atmosphere's tensors (skeleton, cube bank) and episodes' params and state cast to float64."""
    for name, value in list(vars(atm).items()):
        if isinstance(value, torch.Tensor) and value.is_floating_point():
            setattr(atm, name, value.double())
    return tuple(td.apply(lambda v: v.double() if v.is_floating_point() else v) for td in parts)


def _applied_wind_jacobian(atm: Atmosphere, params: TensorDict, st: TensorDict, x: torch.Tensor, h: float) -> torch.Tensor:
    """``[N, 3, 3]`` central-difference Jacobian of the total wind ``Atmosphere.sample`` applies."""
    cols = []
    for j in range(3):
        e = torch.zeros(3, dtype=x.dtype)
        e[j] = h
        cols.append((atm.sample(params, st, x + e, CONTROL_DT)[1] - atm.sample(params, st, x - e, CONTROL_DT)[1]) / (2 * h))
    return torch.stack(cols, -1)


def _stability_cases(n: int, alpha: float, length: float) -> dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(2)
    return scenario(
        n, traj_id="racetrack_h", altitude_m=80.0, wind_speed_ref_m_s=7.0, shear_alpha=alpha, veer_deg_per_100m=8.0,
        wind_dir_deg=torch.rand(n, generator=gen) * 360.0, turb_intensity=0.2, turb_length_scale_m=length,
        stability=torch.arange(n) % 3, turb_seed=torch.arange(n) + 77,
    )  # fmt: skip


def _field_points(n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Positions around 80 m and advection offsets of up to a few km (after a long flight)."""
    gen = torch.Generator().manual_seed(3)
    offset = torch.randn(n, 3, dtype=torch.float64, generator=gen) * 2000.0
    offset[:, 2] = 0.0
    x = torch.randn(n, 3, dtype=torch.float64, generator=gen) * 100.0
    x[:, 2] = 60.0 + 40.0 * torch.rand(n, dtype=torch.float64, generator=gen)
    return x, offset


@pytest.mark.parametrize("length", [60.0, 300.0])
def test_applied_anisotropic_wind_is_divergence_free(length):
    """Central differences in float64 of the wind ``sample`` returns, in every stability regime:
    rms divergence / rms Frobenius norm of the gradient ~1e-7 (the float32 skeleton and
    per-episode maps). With shear exponent alpha = the intensity's altitude exponent, sigma_u
    does not vary with height, so this is the anisotropy construction alone; the old per-component
    scaling gave 0.13 (neutral) and 0.05 (convective) here."""
    cfg = TurbulenceConfig()
    atm = Atmosphere(WindProfileConfig(), cfg)
    n = 96
    params, st = _float64(atm, atm.init(_stability_cases(n, cfg.intensity_altitude_exponent, length)))
    x, st["air_offset"] = _field_points(n)
    jac = _applied_wind_jacobian(atm, params, st, x, h=1e-4)  # shortest wavelength 2 pi L / 800 >= 0.47 m
    div = jac.diagonal(dim1=-2, dim2=-1).sum(-1)
    for regime in (NEUTRAL, STABLE, CONVECTIVE):
        rows = torch.arange(n) % 3 == regime
        ratio = div[rows].pow(2).mean().sqrt() / jac[rows].pow(2).sum((-1, -2)).mean().sqrt()
        assert ratio < 1e-6, (regime, ratio.item())


def test_only_the_altitude_dependence_of_sigma_leaves_a_divergence():
    """With shear, sigma_u(z) = I U(z) (z / z_ref)^-e varies with height and the applied wind's
    divergence is exactly sigma_u'(z) / sigma_u * w (the product rule; nothing else); at 80 m
    with the default shear and L = 60 m it is below 1e-3 of the gradient (docs/atmosphere.md
    2.3 gives its size over the designs)."""
    cfg = TurbulenceConfig()
    atm = Atmosphere(WindProfileConfig(), cfg)
    n = 96
    alpha = 0.14
    params, st = _float64(atm, atm.init(_stability_cases(n, alpha, 60.0)))
    x, st["air_offset"] = _field_points(n)
    jac = _applied_wind_jacobian(atm, params, st, x, h=1e-4)
    div = jac.diagonal(dim1=-2, dim2=-1).sum(-1)
    mean, total, _ = atm.sample(params, st, x, CONTROL_DT)
    predicted = (alpha - cfg.intensity_altitude_exponent) / x[:, 2] * (total - mean)[:, 2]
    torch.testing.assert_close(div, predicted, rtol=1e-3, atol=5e-6)  # gradient terms are O(1) per s
    for regime in (NEUTRAL, STABLE, CONVECTIVE):
        rows = torch.arange(n) % 3 == regime
        ratio = div[rows].pow(2).mean().sqrt() / jac[rows].pow(2).sum((-1, -2)).mean().sqrt()
        assert ratio < 1e-3, (regime, ratio.item())


def test_ensemble_covariance_is_the_regime_tensor_and_rotations_uniform():
    """Pooled over sub-envs (random rotations), the unit gust in the anchor frame has variances
    (1, r_v^2, r_w^2) and no cross-covariance; E[R] = 0 for rotations uniform on SO(3)."""
    cfg = TurbulenceConfig()
    atm = Atmosphere(WindProfileConfig(), cfg)
    n = 4096
    for regime in (NEUTRAL, STABLE, CONVECTIVE):
        params, _ = atm.init(
            scenario(n, traj_id="hover", altitude_m=10.0, wind_dir_deg=90.0, turb_length_scale_m=50.0,
                     stability=regime, turb_seed=torch.arange(n) * 3 + 1)
        )  # fmt: skip
        gen = torch.Generator().manual_seed(3)
        pts = (torch.rand(8, n, 3, generator=gen) - 0.5) * 5000.0  # 8 points 100 L apart per sub-env
        g = atm.unit_gust(params, pts).double().reshape(-1, 3)
        local = torch.stack((-g[:, 0], -g[:, 1], g[:, 2]), -1)  # an easterly blows west; across is south
        cov = local.T @ local / local.shape[0]
        r_v, r_w = cfg.stability_ratios[regime]
        expected = torch.tensor([1.0, r_v**2, r_w**2], dtype=torch.float64)
        torch.testing.assert_close(cov.diagonal() / expected, torch.ones(3, dtype=torch.float64), rtol=0, atol=0.05)
        off = cov - torch.diag(cov.diagonal())
        assert off.abs().max() < 0.04
    iso = Atmosphere(WindProfileConfig(), TurbulenceConfig(stability_ratios=((1.0, 1.0),) * 3))
    params, _ = iso.init(scenario(n, traj_id="hover", altitude_m=10.0, turb_seed=torch.arange(n) * 3 + 1))
    r = params["field_out"].double()  # the anchor frame (fixed: from 0 deg at 10 m) times R
    assert r.mean(0).abs().max() < 4 * (1 / 3 / n) ** 0.5
    torch.testing.assert_close(r @ r.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(n, 3, 3), rtol=0, atol=1e-5)


# --- turbulence: realised statistics through Atmosphere.sample --------------------------------

SPEC_N = 384  # sub-envs, 128 per stability regime
SPEC_STEPS = 4096  # control steps of 10 ms
SPEC_Z = 80.0  # m; hover altitude (above z_ref: exercises shear, veer and the altitude decay)
SPEC_U = 10.0  # m/s, the mean wind at SPEC_Z
SPEC_ALPHA = 0.2
SPEC_I = 0.1
SPEC_L = 5.0  # m: the field is scale-free in k L (test above), so 0.1 m per step = L / 50 and
# 4096 steps = 82 L per sub-env, at the env's own control step


@pytest.fixture(scope="module")
def hover_record():
    return record_hover()


def record_hover():
    """Gust ``[N, T, 3]`` in each sub-env's local mean-wind frame (along, across, up) seen by a
    vehicle holding position while the field is advected past it, and each row's sigma_u."""
    atm = Atmosphere(WindProfileConfig(), TurbulenceConfig())
    n = SPEC_N
    gen = torch.Generator().manual_seed(4)
    u_ref = SPEC_U / (SPEC_Z / 10.0) ** SPEC_ALPHA
    params, st = atm.init(
        scenario(n, traj_id="hover", altitude_m=SPEC_Z, wind_speed_ref_m_s=u_ref, shear_alpha=SPEC_ALPHA, veer_deg_per_100m=6.0,
                 wind_dir_deg=torch.rand(n, generator=gen) * 360.0, turb_intensity=SPEC_I,
                 turb_length_scale_m=SPEC_L, stability=torch.arange(n) % 3, turb_seed=torch.arange(n) + 1000)
    )  # fmt: skip
    pos = torch.zeros(n, 3)
    pos[:, 2] = SPEC_Z
    out = torch.empty(n, SPEC_STEPS, 3)
    with torch.no_grad():
        for k in range(SPEC_STEPS):
            mean, total, st = atm.sample(params, st, pos, CONTROL_DT)
            out[:, k] = to_local(total - mean, mean)
    speed = mean[:, :2].norm(dim=-1)
    torch.testing.assert_close(speed, torch.full((n,), SPEC_U), rtol=1e-5, atol=1e-5)
    sigma_u = SPEC_I * SPEC_U * (SPEC_Z / 10.0) ** -0.05  # by hand
    return out.double(), sigma_u, (torch.arange(n) % 3)


@pytest.mark.parametrize("regime", [NEUTRAL, STABLE, CONVECTIVE])
def test_realised_variance_per_component_and_anisotropy(hover_record, regime):
    gust, sigma_u, stability = hover_record
    ratio_v, ratio_w = TurbulenceConfig().stability_ratios[regime]
    g = gust[stability == regime]
    std = (g**2).mean((0, 1)).sqrt()  # about the known zero mean: unbiased on finite records
    requested = torch.tensor([sigma_u, ratio_v * sigma_u, ratio_w * sigma_u], dtype=torch.float64)
    var_ratio = (std / requested) ** 2
    assert ((var_ratio - 1).abs() < 0.10).all(), f"realised var / requested = {var_ratio.tolist()}"
    # the anisotropy ratios as configured
    assert abs(std[1] / std[0] / ratio_v - 1) < 0.07, (std[1] / std[0]).item()
    assert abs(std[2] / std[0] / ratio_w - 1) < 0.07, (std[2] / std[0]).item()


def _pooled_longitudinal_spectrum(hover_record):
    gust, sigma_u, _ = hover_record
    dx = SPEC_U * CONTROL_DT  # m between consecutive samples
    along = (gust[..., 0] / sigma_u).numpy()
    f, p = welch(along, fs=1.0 / dx, nperseg=2048, detrend=False, axis=-1)  # per cycle/m
    k = 2 * np.pi * f[1:]
    return k, p.mean(0)[1:] / (2 * np.pi)  # one-sided, per rad/m, unit sigma


def test_longitudinal_spectrum_is_von_karman_with_the_requested_length_scale(hover_record):
    k, phi = _pooled_longitudinal_spectrum(hover_record)
    fit = k * SPEC_L < 30.0  # below aliasing (Nyquist is k L = 157)

    def log_model(k, log_l, s2):
        return np.log(von_karman_longitudinal(torch.from_numpy(k), math.exp(log_l), math.sqrt(s2)).numpy())

    (log_l, s2), _ = curve_fit(log_model, k[fit], np.log(phi[fit]), p0=(math.log(2 * SPEC_L), 0.5))
    length = math.exp(log_l)
    assert abs(length / SPEC_L - 1) < 0.20, f"fitted L = {length:.3f} m for {SPEC_L} m"
    assert abs(s2 - 1) < 0.15, s2
    # and the whole measured spectrum lies on the analytic one, averaged over bands of a quarter
    # decade from k L = 0.5 to 30 (a finite set of modes gives a line spectrum: single Welch bins
    # scatter by a few tens of % at high k, where few modes project into each bin)
    model = von_karman_longitudinal(torch.from_numpy(k), SPEC_L).numpy()
    edges = np.geomspace(0.5, 30.0, 8) / SPEC_L
    ratios = [phi[(k >= a) & (k < b)].mean() / model[(k >= a) & (k < b)].mean() for a, b in zip(edges[:-1], edges[1:])]
    assert np.abs(np.array(ratios) - 1).max() < 0.10, np.round(ratios, 3)


def test_inertial_range_slope_is_minus_five_thirds(hover_record):
    k, phi = _pooled_longitudinal_spectrum(hover_record)
    band = (k * SPEC_L > 5.0) & (k * SPEC_L < 40.0)
    slope = np.polyfit(np.log(k[band]), np.log(phi[band]), 1)[0]
    assert abs(slope + 5.0 / 3.0) < 0.15, slope


# --- the paper's grid layout -----------------------------------------------------------------


@pytest.fixture(scope="module")
def grid_atmosphere():
    return Atmosphere(WindProfileConfig(), TurbulenceConfig(layout="paper_grid"))  # ~35 s: the cube bank


def test_paper_grid_interpolates_the_cube_trilinearly_with_wrap_around(grid_atmosphere):
    """At cell centres the cube's own values, the same a cube size away in every direction
    (periodic wrap), and the average of two neighbours halfway between them."""
    atm = grid_atmosphere
    cfg = atm.turbulence
    h = cfg.cube_size_m / cfg.cube_points
    gen = torch.Generator().manual_seed(8)
    n = 64
    cube = torch.randint(0, atm.cube_bank.shape[0], (n,), generator=gen)
    idx = torch.randint(0, cfg.cube_points, (n, 3), generator=gen)
    centre = (idx.float() + 0.5) * h
    at = atm._interpolate_cube(cube, list(centre.unbind(-1)))
    expected = atm.cube_bank[cube, idx[:, 0], idx[:, 1], idx[:, 2]]
    torch.testing.assert_close(at, expected, rtol=0, atol=1e-6)
    shift = torch.tensor([1.0, -2.0, 3.0]) * cfg.cube_size_m
    torch.testing.assert_close(atm._interpolate_cube(cube, list((centre + shift).unbind(-1))), expected, rtol=0, atol=1e-4)
    last = idx.clone()
    last[:, 0] = cfg.cube_points - 1  # halfway across the wrap: between cell P-1 and cell 0
    half = (last.float() + 0.5) * h + torch.tensor([0.5 * h, 0.0, 0.0])
    neighbours = atm.cube_bank[cube, last[:, 0], last[:, 1], last[:, 2]] + atm.cube_bank[cube, 0, last[:, 1], last[:, 2]]
    torch.testing.assert_close(atm._interpolate_cube(cube, list(half.unbind(-1))), 0.5 * neighbours, rtol=0, atol=1e-5)


@pytest.mark.parametrize("length_index", [0, -1])
def test_paper_grid_cubes_hold_the_variance_of_their_k_range(grid_atmosphere, length_index):
    """TurboGenPY's amplitudes without renormalisation: the bank's cubes at one length scale
    realise (within 10 %, pooled over realisations and components) the variance the von Karman
    spectrum holds between 2 pi / 1200 m and the grid Nyquist pi / 18.75 m: 60-90 % of it."""
    atm = grid_atmosphere
    cfg = atm.turbulence
    length = cfg.cube_length_scales_m[length_index]
    first = (length_index % len(cfg.cube_length_scales_m)) * cfg.cube_bank_size
    var = atm.cube_bank[first : first + cfg.cube_bank_size].double().pow(2).mean()
    k_min, k_max = 2 * math.pi / cfg.cube_size_m, math.pi / (cfg.cube_size_m / cfg.cube_points)
    held = quad(lambda k: von_karman_energy(torch.tensor(k, dtype=torch.float64), length).item(), k_min, k_max,
                limit=200)[0] / 1.5  # fmt: skip
    assert 0.55 < held < 0.95
    assert abs(var / held - 1) < 0.10, f"var {var.item():.3f} vs predicted {held:.3f}"


def test_paper_grid_episodes_pick_the_nearest_length_scale_and_their_own_cube(grid_atmosphere):
    atm = grid_atmosphere
    cfg = atm.turbulence
    lengths = torch.tensor([55.0, 70.0, 80.0, 250.0, 400.0])
    params, _ = atm.init(scenario(5, turb_length_scale_m=lengths, turb_seed=torch.arange(5)))
    nearest = torch.tensor([0, 0, 1, 4, 4])  # 60 | 90 split at sqrt(60 x 90) = 73.5 m (log L)
    assert torch.equal(params["cube"] // cfg.cube_bank_size, nearest)
    assert ((params["cube_offset"] >= 0) & (params["cube_offset"] < cfg.cube_size_m)).all()


# --- replay: a row's wind does not depend on its batch ----------------------------------------


@pytest.mark.parametrize("layout", ["full", "paper_grid"])
def test_a_row_alone_and_in_a_large_batch_gives_bitwise_identical_wind(layout, request):
    # the paper grid's atmosphere is the module's (the same construction; building its cube bank
    # again cost 8 s of CPU): nothing here or in the tests sharing it changes it
    atm = (request.getfixturevalue("grid_atmosphere") if layout == "paper_grid"
           else Atmosphere(WindProfileConfig(), TurbulenceConfig(layout=layout)))
    big = sample_regimes(700, RegimeRanges(), seed=21)
    order = torch.randperm(700, generator=torch.Generator().manual_seed(6))
    rows = [3, 350, 699]
    gen = torch.Generator().manual_seed(7)
    start = torch.randn(700, 3, generator=gen) * 100.0
    start[:, 2] = big["altitude_m"]
    vel = torch.randn(700, 3, generator=gen) * 5.0

    def run(index: torch.Tensor, threads: int):
        sc = {k: v[index] for k, v in big.items()}
        old = torch.get_num_threads()
        torch.set_num_threads(threads)
        try:
            (params, st), pos, out = atm.init(sc), start[index].clone(), []
            for _ in range(40):
                mean, total, st = atm.sample(params, st, pos, CONTROL_DT)
                out.append(torch.cat((mean, total, st["air_offset"]), -1))
                pos = pos + CONTROL_DT * vel[index]
        finally:
            torch.set_num_threads(old)
        return torch.stack(out, 1)

    batch = run(order, threads=2)
    where = {int(r): i for i, r in enumerate(order)}
    for r in rows:
        alone = run(torch.tensor([r]), threads=1)
        assert torch.equal(alone[0], batch[where[r]]), f"row {r} (index {where[r]} in the batch) differs"
    pair = run(torch.tensor(rows[:2]), threads=1)
    assert torch.equal(pair[1], batch[where[rows[1]]])
