"""Sensor suite statistics (noise, sample-and-hold, Gauss-Markov and legacy random-walk biases,
the 200 Hz IMU, replay) and the counter-based random numbers they are drawn from."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from quadwind_trl.config import LEGACY_SENSORS, SENSOR_PRESETS, SensorChannelConfig, SensorConfig, TimingConfig
from quadwind_trl.envs.counter_rng import hash_bits, hash_normal, hash_uniform
from quadwind_trl.envs.sensors import CHANNEL_NAMES, SensorSuite, pack_channels, unpack_channels

DT = TimingConfig().control_dt_s
CFG = SensorConfig()
PER_CHANNEL = [CFG.gps_pos] * 3 + [CFG.gps_vel] * 3 + [CFG.baro_alt] + [CFG.attitude_rp] * 2 + [CFG.attitude_yaw] + [
    CFG.gyro
] * 3 + [CFG.accel] * 3
NOISE = torch.tensor([c.noise_std for c in PER_CHANNEL], dtype=torch.float64)
# control steps between samples at 100 Hz: GPS 10 Hz, baro 25 Hz, attitude 50 Hz; gyro/accel at
# 200 Hz take two samples per control step (one per step where the suite is driven alone)
PERIOD = torch.tensor([10] * 6 + [4] + [2] * 3 + [1] * 6)
IMU_SAMPLES = torch.tensor([1] * 10 + [2] * 6)
# the suite's channels packed (pack_channels) so the statistics run over all of them at once
NUM_CHANNELS = len(CHANNEL_NAMES)
YAW = CHANNEL_NAMES.index("attitude.yaw")
IMU_NAMES = ("gyro", "accel")
IMU = slice(CHANNEL_NAMES.index("gyro.p"), CHANNEL_NAMES.index("accel.z") + 1)
GROUPS = {"gps_pos": [0, 1, 2], "gps_vel": [3, 4, 5], "baro": [6], "roll_pitch": [7, 8], "yaw": [9], "gyro": [10, 11, 12],
          "accel": [13, 14, 15]}  # fmt: skip
assert [CHANNEL_NAMES[c] for c in GROUPS["yaw"] + GROUPS["gyro"]] == ["attitude.yaw", "gyro.p", "gyro.q", "gyro.r"]


def measure(suite: SensorSuite, params, state, truth: torch.Tensor, k: int, first: bool = False,
            imu_truth_sub: torch.Tensor | None = None) -> tuple[torch.Tensor, object]:
    """``suite.measure`` on packed truth ``[n, 16]`` (and IMU sub-samples ``[n, m - 1, 6]``),
    returning the named measurements packed."""
    n = truth.shape[0]
    sub = None if imu_truth_sub is None else unpack_channels(imu_truth_sub, IMU_NAMES)
    meas, state = suite.measure(params, state, unpack_channels(truth), torch.full((n,), k),
                                force=torch.ones(n, 1, dtype=torch.bool) if first else None, imu_truth_sub=sub)
    return pack_channels(meas), state


def wrap(angle: torch.Tensor) -> torch.Tensor:
    return torch.remainder(angle + math.pi, 2 * math.pi) - math.pi


def random_truth(n: int, gen: torch.Generator) -> torch.Tensor:
    truth = torch.randn(n, NUM_CHANNELS, generator=gen) * 3.0
    truth[:, YAW] = (torch.rand(n, generator=gen) * 2 - 1) * 3.1
    return truth


def test_paper_noise_levels_and_rates():
    assert (CFG.gps_pos.rate_hz, CFG.gps_pos.noise_std) == (10.0, 0.7)
    assert (CFG.gps_vel.rate_hz, CFG.gps_vel.noise_std) == (10.0, 0.15)
    assert (CFG.baro_alt.rate_hz, CFG.baro_alt.noise_std) == (25.0, 0.8)
    assert CFG.attitude_rp.rate_hz == CFG.attitude_yaw.rate_hz == 50.0
    assert math.isclose(CFG.attitude_rp.noise_std, math.radians(0.6))
    assert math.isclose(CFG.attitude_yaw.noise_std, math.radians(1.5))
    assert (CFG.gyro.rate_hz, CFG.accel.rate_hz) == (200.0, 200.0)
    assert math.isclose(CFG.gyro.noise_std, math.radians(0.3)) and CFG.accel.noise_std == 0.05
    suite = SensorSuite(CFG, DT)
    assert torch.equal(suite.period.cpu(), PERIOD) and suite.imu_samples_per_step == 2
    # exact discretisation over each instrument's own sample interval
    h = (PERIOD * DT / IMU_SAMPLES).double()
    tau = torch.tensor([c.bias_corr_time_s for c in PER_CHANNEL], dtype=torch.float64)
    sigma = torch.tensor([c.bias_std for c in PER_CHANNEL], dtype=torch.float64)
    torch.testing.assert_close(suite.bias_decay.double(), torch.exp(-h / tau), rtol=1e-6, atol=0)
    torch.testing.assert_close(suite.bias_step_std.double(), sigma * (1 - torch.exp(-2 * h / tau)).sqrt(), rtol=1e-5, atol=0)


def test_every_preset_is_bounded_except_the_legacy_walk():
    for name, (sensors, _) in SENSOR_PRESETS.items():
        sensors.validate()
        bounded = [math.isfinite(ch.bias_corr_time_s) for ch in sensors.channels().values()]
        assert all(bounded) if name != "legacy_walk" else not any(bounded), name
    # the receiver classes order as their datasheets: RTK centimetres, SBAS and standalone metres
    std = {name: SENSOR_PRESETS[name][0].gps_pos.bias_std for name in ("rtk", "sbas", "standalone")}
    assert std["rtk"] < 0.02 < 0.5 < std["sbas"] < std["standalone"]
    assert LEGACY_SENSORS.gyro.rate_hz == 100.0  # what it always sampled at


def test_rates_that_do_not_divide_the_control_rate_are_refused():
    with pytest.raises(ValueError, match=r"gps_pos\.x \(SensorConfig\.gps_pos\)"):
        SensorSuite(replace(CFG, gps_pos=SensorChannelConfig(30.0, 0.7, 0.05)), DT)
    with pytest.raises(ValueError, match="baro_alt"):
        SensorSuite(replace(CFG, baro_alt=SensorChannelConfig(200.0, 0.8)), DT)


def test_disabled_sensors_return_the_truth():
    suite = SensorSuite(replace(CFG, enabled=False), DT)
    truth = torch.randn(5, NUM_CHANNELS)
    meas, _ = measure(suite, *suite.init(torch.arange(5)), truth, 0)
    assert torch.equal(meas, truth)


def test_white_noise_std_per_channel_with_bias_disabled():
    cfg = SensorConfig(**{
        name: SensorChannelConfig(getattr(CFG, name).rate_hz, getattr(CFG, name).noise_std, 0.0)
        for name in ("gps_pos", "gps_vel", "baro_alt", "attitude_rp", "attitude_yaw", "gyro", "accel")
    })  # fmt: skip
    suite = SensorSuite(cfg, DT)
    n = 1024
    params, st = suite.init(torch.arange(n) + 10_000)
    gen = torch.Generator().manual_seed(0)
    sq, count = torch.zeros(NUM_CHANNELS, dtype=torch.float64), torch.zeros(NUM_CHANNELS)
    for k in range(100):
        truth = random_truth(n, gen)
        meas, st = measure(suite, params, st, truth, k, first=k == 0)
        err = meas - truth
        err[:, YAW] = wrap(err[:, YAW])
        tick = (k % PERIOD) == 0
        sq += torch.where(tick, (err.double() ** 2).sum(0), 0.0)
        count += tick * n
    std = (sq / count).sqrt()
    assert ((std / NOISE - 1).abs() < 0.05).all(), dict(zip(CHANNEL_NAMES, (std / NOISE).tolist()))


def _long_run(cfg: SensorConfig, n: int, steps: int = 800):
    suite = SensorSuite(cfg, DT)
    params, st = suite.init(torch.arange(n) * 3 + 5)
    gen = torch.Generator().manual_seed(1)
    noise, increments, bias_at = [], [], {}
    for k in range(steps):
        truth = random_truth(n, gen)
        before = st["bias"]
        meas, st = measure(suite, params, st, truth, k, first=k == 0)
        if k < 200:
            err = meas - truth - st["bias"]
            err[:, YAW] = wrap(err[:, YAW])
            tick = (k % PERIOD) == 0
            noise.append(torch.where(tick, err, float("nan")))
            increments.append(torch.where(tick, st["bias"] - before, float("nan")))
        if k in (199, 799):
            bias_at[k] = st["bias"].double()
    # noise and bias increments [n, 200, 16], nan between an instrument's samples
    return torch.stack(noise, 1).double(), bias_at, torch.stack(increments, 1).double()


@pytest.fixture(scope="module")
def long_run():
    """2048 seeds, 800 control steps (8 s) of the default suite, random truth every step."""
    return _long_run(CFG, 2048)


@pytest.fixture(scope="module")
def long_walk():
    """The same with the legacy random-walk biases."""
    return _long_run(LEGACY_SENSORS, 1024)


def test_noise_std_per_channel_with_the_bias_removed(long_run):
    noise, _, _ = long_run
    std = noise.nan_to_num().pow(2).sum((0, 1)).div((~noise.isnan()).sum((0, 1))).sqrt()
    assert ((std / NOISE - 1).abs() < 0.05).all(), dict(zip(CHANNEL_NAMES, (std / NOISE).tolist()))


def test_noise_is_white_and_uncorrelated_across_channels_and_with_the_bias(long_run):
    noise, _, increments = long_run
    z = noise / NOISE
    for c, p in enumerate(PERIOD.tolist()):
        ticks = z[:, ::p, c]  # consecutive samples of one instrument
        lag1 = (ticks[:, 1:] * ticks[:, :-1]).mean() / ticks.pow(2).mean()
        assert abs(lag1) < 0.03, (CHANNEL_NAMES[c], lag1.item())
    common = z[:, ::20].reshape(-1, NUM_CHANNELS)  # steps where every channel ticks (lcm 20)
    corr = torch.corrcoef(common.T)
    assert (corr - torch.eye(NUM_CHANNELS, dtype=torch.float64)).abs().max() < 0.04
    # the white noise and the bias step drawn at the same sample are independent
    for c, p in enumerate(PERIOD.tolist()):
        pair = torch.stack((noise[:, ::p, c].flatten(), increments[:, ::p, c].flatten()))
        assert abs(torch.corrcoef(pair)[0, 1]) < 0.03, CHANNEL_NAMES[c]


def test_legacy_bias_random_walk_variance_grows_linearly_in_time(long_walk):
    """Ticks at steps 0, p, 2p ...: after steps 0..k, k + 1 divisible by every period, the bias
    variance is walk^2 (k + 1) dt exactly: 2 s and 8 s here, a ratio of 4."""
    _, bias, _ = long_walk
    t1, t2 = 200 * DT, 800 * DT
    for name, chans in GROUPS.items():
        v1 = bias[199][:, chans].pow(2).mean()  # zero-mean walk: about zero
        v2 = bias[799][:, chans].pow(2).mean()
        walk2 = LEGACY_SENSORS.channels()[_CHANNEL_OF[name]].bias_drive_std_per_sqrt_s ** 2
        assert abs(v2 / v1 / (t2 / t1) - 1) < 0.10, (name, (v2 / v1).item())
        assert abs(v1 / (walk2 * t1) - 1) < 0.10, (name, (v1 / (walk2 * t1)).item())
        assert abs(v2 / (walk2 * t2) - 1) < 0.10, (name, (v2 / (walk2 * t2)).item())


_CHANNEL_OF = {"gps_pos": "gps_pos", "gps_vel": "gps_vel", "baro": "baro_alt", "roll_pitch": "attitude_rp",
               "yaw": "attitude_yaw", "gyro": "gyro", "accel": "accel"}


def test_gauss_markov_bias_has_its_stationary_std_and_correlation_time():
    """Every channel a Gauss-Markov bias with tau = 1.5 s: from the stationary start, the std
    stays sigma at every time and the lag-1 s autocorrelation is exp(-1 / tau) (tau within 10 %)."""
    tau = 1.5
    cfg = SensorConfig(**{name: SensorChannelConfig.gauss_markov(ch.rate_hz, ch.noise_std, 2.0 * ch.noise_std + 0.01, tau)
                          for name, ch in CFG.channels().items()})  # fmt: skip
    suite = SensorSuite(cfg, DT)
    sigma = suite.bias_std.double()
    n, lag, steps = 4096, 100, 600
    params, st = suite.init(torch.arange(n) * 11 + 1)
    truth, imu_sub = torch.zeros(n, NUM_CHANNELS), torch.zeros(n, 1, 6)  # the IMU's 5 ms sample too
    biases = []
    for k in range(steps):
        _, st = measure(suite, params, st, truth, k, first=k == 0, imu_truth_sub=None if k == 0 else imu_sub)
        biases.append(st["bias"].double())
    b = torch.stack(biases, 1) / sigma  # [n, steps, 16], unit variance if stationary
    for t in (0, steps // 2, steps - 1):
        std = b[:, t].pow(2).mean(0).sqrt()
        assert ((std - 1).abs() < 0.10).all(), (t, std)
    rho = (b[:, lag:] * b[:, :-lag]).mean((0, 1)) / b.pow(2).mean((0, 1))
    tau_hat = -(lag * DT) / rho.log()
    assert ((tau_hat / tau - 1).abs() < 0.10).all(), dict(zip(CHANNEL_NAMES, tau_hat.tolist()))


def test_the_default_biases_start_from_their_stationary_distribution():
    suite = SensorSuite(CFG, DT)
    bias = suite.init(torch.arange(20_000) + 77)[1]["bias"].double()
    ratio = bias.pow(2).mean(0).sqrt() / suite.bias_std.double()
    assert ((ratio - 1).abs() < 0.05).all(), ratio
    assert (bias.mean(0).abs() < 0.05 * suite.bias_std.double()).all()


def test_the_imu_delivers_a_new_sample_every_5_ms():
    """Two gyro/accel samples per 10 ms control step: the intermediate one (from the physics state
    the simulator hands in) and the control-instant one, each with its own noise."""
    cfg = SensorConfig(**{name: SensorChannelConfig(ch.rate_hz, ch.noise_std) for name, ch in CFG.channels().items()})
    suite = SensorSuite(cfg, DT)
    assert suite.imu_substeps(TimingConfig().control_substeps) == (2,)  # the 4 ms state for the 5 ms sample
    assert SensorSuite(LEGACY_SENSORS, DT).imu_substeps(5) == ()
    n = 4096
    params, st = suite.init(torch.arange(n))
    gen = torch.Generator().manual_seed(4)
    mid_err, end_err = [], []
    for k in range(40):
        truth, mid_truth = random_truth(n, gen), random_truth(n, gen)[:, IMU]
        sub = None if k == 0 else mid_truth.unsqueeze(-2)
        meas, st = measure(suite, params, st, truth, k, first=k == 0, imu_truth_sub=sub)
        if k:
            mean = torch.cat([suite.imu_mean(st, name) for name in IMU_NAMES], -1)
            mid = 2 * mean - meas[:, IMU]  # the 5 ms sample
            mid_err.append(mid - mid_truth)
            end_err.append(meas[:, IMU] - truth[:, IMU])
    mid_err, end_err = torch.cat(mid_err).double(), torch.cat(end_err).double()
    noise = NOISE[IMU]
    assert ((mid_err.std(0) / noise - 1).abs() < 0.05).all() and ((end_err.std(0) / noise - 1).abs() < 0.05).all()
    corr = torch.corrcoef(torch.cat((mid_err, end_err), 1).T)[:6, 6:].diagonal()
    assert (corr.abs() < 0.03).all(), corr  # independent draws: two samples, not one held twice


def test_values_change_only_at_each_sensors_rate_and_hold_in_between():
    suite = SensorSuite(CFG, DT)
    n, first = 8, 37  # an episode starting off the sampling grid: sampled at once, then on the grid
    params, st = suite.init(torch.arange(n))
    gen = torch.Generator().manual_seed(2)
    prev, sampled_truth = None, None
    for k in range(first, first + 60):
        truth = random_truth(n, gen)
        meas, st = measure(suite, params, st, truth, k, first=k == first)
        tick = ((k % PERIOD) == 0) | (k == first)
        if prev is not None:
            changed = (meas != prev).all(0)
            held = (meas == prev).all(0)
            assert torch.equal(changed, tick) and torch.equal(held, ~tick), (k, changed, tick)
        # a held value is the last sample's truth plus its error, not the current truth
        sampled_truth = torch.where(tick, truth, sampled_truth) if sampled_truth is not None else truth
        err = meas - sampled_truth
        err[:, YAW] = wrap(err[:, YAW])
        assert (err.abs() < 6 * NOISE.float() + 0.05).all()
        assert (meas[:, YAW] >= -math.pi).all() and (meas[:, YAW] < math.pi).all()
        prev = meas


def test_one_seed_replays_identically_alone_or_in_a_batch():
    suite = SensorSuite(CFG, DT)
    n, row = 1000, 613
    seeds = torch.arange(n) * 7 + 3
    gen = torch.Generator().manual_seed(3)
    truths = [random_truth(n, gen) for _ in range(120)]

    def run(index: torch.Tensor, threads: int) -> torch.Tensor:
        old = torch.get_num_threads()
        torch.set_num_threads(threads)
        try:
            (params, st), out = suite.init(seeds[index]), []
            for k, truth in enumerate(truths):
                meas, st = measure(suite, params, st, truth[index], k, first=k == 0)
                out.append(torch.cat((meas, st["bias"]), -1))
        finally:
            torch.set_num_threads(old)
        return torch.stack(out, 1)

    batch = run(torch.arange(n), threads=2)
    alone = run(torch.tensor([row]), threads=1)
    assert torch.equal(alone[0], batch[row])
    shuffled = torch.tensor([5, row, 999])
    assert torch.equal(run(shuffled, threads=1)[1], batch[row])
    assert not torch.equal(batch[row], batch[row + 1])  # another seed is another stream


# --- counter-based random numbers --------------------------------------------------------------


def test_hash_normal_is_standard_normal_and_independent():
    keys = torch.arange(50_000)
    x = hash_normal(keys, 7, 201, 16).double()
    assert abs(x.mean()) < 0.005 and abs(x.var() - 1) < 0.01
    assert abs((x**4).mean() / x.var() ** 2 - 3) < 0.05  # Gaussian kurtosis
    assert abs((x > 1.96).double().mean() - 0.025) < 0.002
    corr = torch.corrcoef(x.T) - torch.eye(16, dtype=torch.float64)
    assert corr.abs().max() < 0.02  # columns
    assert abs(torch.corrcoef(torch.stack((x[:-1].flatten(), x[1:].flatten())))[0, 1]) < 0.01  # adjacent keys
    y = hash_normal(torch.full((50_000,), 123), torch.arange(50_000), 201, 4).double()
    assert abs(torch.corrcoef(torch.stack((y[:-1].flatten(), y[1:].flatten())))[0, 1]) < 0.01  # adjacent counters
    other = hash_normal(keys, 7, 202, 16).double()
    assert abs(torch.corrcoef(torch.stack((x.flatten(), other.flatten())))[0, 1]) < 0.01  # streams


def test_hash_uniform_is_uniform_in_the_open_interval():
    u = hash_uniform(torch.arange(100_000), 3, 5, 4).double().flatten()
    assert u.min() > 0 and u.max() < 1
    counts = torch.histc(u, bins=50, min=0, max=1)
    expected = u.numel() / 50
    chi2 = ((counts - expected) ** 2 / expected).sum().item()
    assert chi2 < 95.0  # 49 dof: the 99.99 % point is ~95


def test_hash_rows_are_pure_functions_of_key_and_counter():
    keys = torch.tensor([0, 1, 2**40 + 5, -3, 2**62])
    counters = torch.tensor([0, 10**9, 7, 2**33, -1])
    full = hash_bits(keys, counters, 9, 6)
    assert (full >= 0).all() and (full < 2**32).all()
    perm = torch.tensor([3, 0, 4, 1, 2])
    assert torch.equal(hash_bits(keys[perm], counters[perm], 9, 6), full[perm])
    for i in range(5):
        assert torch.equal(hash_bits(keys[i : i + 1], counters[i : i + 1], 9, 6), full[i : i + 1])
    assert torch.equal(hash_bits(keys, counters, 9, 3), full[:, :3])  # columns do not depend on num
    assert (hash_bits(keys, counters, 10, 6) != full).float().mean() > 0.99



def test_a_traced_draw_warns_nothing_and_draws_the_eager_bits():
    """Traced (``torch.compile``), the hash's numbers are made in the graph rather than read from
    their eager cache, which dynamo would trace through with a warning per cached function; the
    draws are the eager ones."""
    import warnings

    from torch._dynamo.utils import warn_once_cache

    keys, counters = torch.tensor([0, 1, 2**40 + 5]), torch.tensor([0, 10**9, 7])
    traced = torch.compile(lambda k, c: (hash_bits(k, c, 9, 6), hash_normal(k, c, 9, 3)), backend="eager", fullgraph=True)
    warn_once_cache.difference_update({m for m in warn_once_cache if "lru_cache" in m})  # dynamo warns once a process
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        bits, normals = traced(keys, counters)
    assert not [w for w in caught if "lru_cache" in str(w.message)]
    assert torch.equal(bits, hash_bits(keys, counters, 9, 6)) and torch.equal(normals, hash_normal(keys, counters, 9, 3))

@pytest.mark.parametrize("reference", ["baro", "gnss"])
def test_height_reference_decides_whether_the_baro_offset_reaches_the_altitude(reference):
    """A vehicle at rest at 100 m, noise-free sensors, the barometer reading 0.15 m high and the
    GNSS height exact: with the barometer as anchor the estimate settles on its bias; with the GNSS
    height it settles on the truth and the filter's offset estimate on the bias (the offset error
    decays with a ~28 s time constant: 240 s is more than eight)."""
    from quadwind_trl.config import NavigationConfig
    from quadwind_trl.envs.navigation import NavigationParams, init_navigation, update_navigation

    meas = unpack_channels(torch.zeros(1, NUM_CHANNELS))
    meas["gps_pos"][:, 2] = 100.0  # GNSS height
    meas["baro_alt"][:, 0] = 100.15  # barometer, biased
    meas["accel"][:, 2] = 9.81  # accelerometer at rest (the filter removes the same g)
    params = NavigationParams.from_config(NavigationConfig(height_reference=reference))
    nav = init_navigation(meas)
    for step in range(1, 24001):
        gps, baro = torch.tensor([[step % 10 == 0]]), torch.tensor([[step % 4 == 0]])
        nav = update_navigation(nav, meas, meas["accel"], gps, baro, params, DT)
    error = nav["pos"][0, 2].item() - 100.0
    if reference == "baro":
        assert abs(error - 0.15) < 1e-3 and nav["baro_offset"].abs().max().item() == 0.0
    else:
        assert abs(error) < 2e-3 and abs(nav["baro_offset"][0, 0].item() - 0.15) < 2e-3
