"""Latin-hypercube wind designs: stratification, the adaptive wind bound, disjoint train and
evaluation designs, the stability cycle, and per-row purity of the random scenarios."""
from __future__ import annotations

import math

import pytest
import torch

from quadwind_trl.config import TurbulenceConfig, WindProfileConfig
from quadwind_trl.envs.atmosphere import Atmosphere
from quadwind_trl.envs.scenarios import (
    SCENARIO_FIELDS,
    RegimeRanges,
    latin_hypercube,
    make_scenarios,
    random_scenarios,
    sample_regimes,
)

VERTICAL = RegimeRanges(altitude_m=None)
HORIZONTAL = RegimeRanges()
REGIME_FIELDS = ("wind_speed_ref_m_s", "wind_dir_deg", "turb_intensity", "shear_alpha", "veer_deg_per_100m",
                 "turb_length_scale_m", "altitude_m")  # fmt: skip


def assert_stratified(u: torch.Tensor, eps: float = 0.0) -> None:
    """Each column of ``u`` ``[n, d]`` has exactly one value in every bin [i/n, (i+1)/n)
    (``eps`` tolerates values recovered from float32 fields sitting on a bin edge)."""
    n = u.shape[0]
    s, _ = u.sort(0)
    lo = torch.arange(n, dtype=torch.float64).unsqueeze(-1) / n
    assert (s >= lo - eps).all() and (s < lo + 1.0 / n + eps).all(), "a bin holds zero or two points"


@pytest.mark.parametrize("n, dims", [(1, 3), (10, 6), (97, 7), (500, 7)])
def test_latin_hypercube_has_one_point_per_bin_in_every_dimension(n, dims):
    u = latin_hypercube(n, dims, seed=3)
    assert u.shape == (n, dims) and u.dtype == torch.float64
    assert (u >= 0).all() and (u < 1).all()
    bins = (u * n).floor().long()
    for d in range(dims):
        assert torch.equal(bins[:, d].sort().values, torch.arange(n))
    assert_stratified(u)


def unit_coordinates(cases, ranges: RegimeRanges) -> torch.Tensor:
    """Invert the design's map from the unit cube to physical regimes (float64)."""
    def unit(name, bounds):
        return (cases[name].double() - bounds[0]) / (bounds[1] - bounds[0])

    alpha = cases["shear_alpha"].double()
    altitude = cases["altitude_m"].double()
    upper = torch.clamp(ranges.wind_ceiling_m_s / (altitude / ranges.reference_height_m) ** alpha, max=ranges.wind_speed_m_s[1])
    cols = [
        (cases["wind_speed_ref_m_s"].double() - ranges.wind_speed_m_s[0]) / (upper - ranges.wind_speed_m_s[0]),
        unit("wind_dir_deg", ranges.wind_dir_deg),
        unit("turb_intensity", ranges.intensity),
        unit("shear_alpha", ranges.shear_alpha),
        unit("veer_deg_per_100m", ranges.veer_deg_per_100m),
        unit("turb_length_scale_m", ranges.length_scale_m),
    ]
    if ranges.altitude_m is not None:
        cols.append(unit("altitude_m", ranges.altitude_m))
    return torch.stack(cols, -1)


@pytest.mark.parametrize("ranges, dims", [(VERTICAL, 6), (HORIZONTAL, 7)])
def test_every_regime_dimension_is_stratified(ranges, dims):
    n = 240
    cases = sample_regimes(n, ranges, seed=11)
    u = unit_coordinates(cases, ranges)
    assert u.shape == (n, dims) == (n, ranges.dims)
    assert_stratified(u, eps=1e-5)  # float32 fields: ~1e-6 relative
    if ranges.altitude_m is None:
        assert (cases["altitude_m"] == ranges.top_altitude_m).all()


def test_regime_ranges_are_the_papers_where_it_gives_them():
    r = RegimeRanges()
    assert r.intensity == (0.08, 0.25) and r.veer_deg_per_100m == (3.0, 8.0)
    assert r.top_altitude_m == 600.0 and r.wind_ceiling_m_s == 20.0 and r.reference_height_m == 10.0


def profile_speed(cases, altitude: torch.Tensor) -> torch.Tensor:
    """The uncapped power-law mean wind at ``altitude``, through Atmosphere.mean_wind."""
    atm = Atmosphere(WindProfileConfig(max_horizontal_wind_m_s=1e9), TurbulenceConfig(enabled=False))
    params, _ = atm.init({k: cases[k] for k in SCENARIO_FIELDS})
    return atm.mean_wind(params, altitude.float())[:, :2].norm(dim=-1).double()


def test_vertical_design_bounds_the_mean_wind_at_the_top_altitude():
    cases = sample_regimes(300, VERTICAL, seed=5)
    top = profile_speed(cases, torch.full((300,), 600.0))
    hand = cases["wind_speed_ref_m_s"].double() * 60.0 ** cases["shear_alpha"].double()  # power law by hand
    torch.testing.assert_close(top, hand, rtol=1e-5, atol=1e-5)
    assert (top <= 20.0 + 1e-4).all(), top.max()
    assert top.max() > 19.0  # the bound is the binding constraint, not a much lower one
    assert (cases["wind_speed_ref_m_s"] >= 1.0).all()


def test_horizontal_design_bounds_the_mean_wind_at_each_flights_own_altitude():
    cases = sample_regimes(300, HORIZONTAL, seed=6)
    own = profile_speed(cases, cases["altitude_m"])
    assert (own <= 20.0 + 1e-4).all(), own.max()
    assert own.max() > 19.0
    # bounded at its own altitude, not at 600 m: low flights get winds that would exceed the
    # ceiling at the top of the vertical range
    assert (profile_speed(cases, torch.full((300,), 600.0)) > 20.5).any()
    assert (cases["altitude_m"] >= 80.0).all() and (cases["altitude_m"] <= 550.0).all()


def test_train_and_evaluation_designs_share_no_point():
    train = sample_regimes(200, HORIZONTAL, seed=1)
    evaluation = sample_regimes(200, HORIZONTAL, seed=2)
    a = torch.stack([train[f].double() for f in REGIME_FIELDS], -1)
    b = torch.stack([evaluation[f].double() for f in REGIME_FIELDS], -1)
    same = (a.unsqueeze(1) == b.unsqueeze(0)).all(-1)
    assert not same.any()
    # no shared value in any continuous dimension, and no shared turbulence or sensor seed
    for f in REGIME_FIELDS:
        assert not (train[f].unsqueeze(1) == evaluation[f].unsqueeze(0)).any(), f
    seeds_train = torch.cat((train["turb_seed"], train["sensor_seed"]))
    seeds_eval = torch.cat((evaluation["turb_seed"], evaluation["sensor_seed"]))
    assert not torch.isin(seeds_train, seeds_eval).any()
    assert seeds_train.unique().numel() == 400  # distinct within a design too
    # and the same seed gives the same design
    again = sample_regimes(200, HORIZONTAL, seed=1)
    for f in SCENARIO_FIELDS:
        assert torch.equal(again[f], train[f]), f


def test_stability_cycles_neutral_stable_convective():
    cases = sample_regimes(10, VERTICAL, seed=4)
    assert cases["stability"].tolist() == [0, 1, 2, 0, 1, 2, 0, 1, 2, 0]


def test_make_scenarios_defaults_broadcast_and_unknown_fields():
    sc = make_scenarios(3, wind_speed_ref_m_s=4.0, turb_seed=torch.tensor([1, 2, 3]), traj_id=0)
    assert sc.batch_size == torch.Size([3])
    assert sc["wind_speed_ref_m_s"].tolist() == [4.0] * 3 and sc["turb_seed"].tolist() == [1, 2, 3]
    assert math.isclose(sc["shear_alpha"][0].item(), 0.14, rel_tol=1e-6)
    with pytest.raises(KeyError, match="wind_speed"):
        make_scenarios(2, wind_speed=3.0)


def test_random_scenarios_rows_are_pure_functions_of_key_and_counter():
    """A row drawn alone equals the same row drawn in a large batch, bitwise."""
    n = 3000
    key = torch.arange(n) * 5 + 1
    counter = torch.arange(n) % 17
    ids = torch.arange(6)
    batch = random_scenarios(key, counter, HORIZONTAL, ids)
    for rows in (torch.tensor([0]), torch.tensor([2999]), torch.tensor([1234, 17, 2500])):
        alone = random_scenarios(key[rows], counter[rows], HORIZONTAL, ids)
        for f in SCENARIO_FIELDS:
            assert torch.equal(alone[f], batch[f][rows]), f
    own = profile_speed(batch, batch["altitude_m"])
    assert (own <= 20.0 + 1e-4).all()
    assert set(batch["stability"].tolist()) == {0, 1, 2} and set(batch["traj_id"].tolist()) == set(range(6))
