"""The feature extractor: channel schema, one code path online/offline (bit for bit), and
hand-checked values."""
from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict

from quadwind_trl.config import EnvConfig, SensorConfig, TurbulenceConfig
from quadwind_trl.estimator.features import (
    HORIZONTAL_CHANNELS,
    RAW_RECORD_KEYS,
    TRAILING_SIGNALS,
    TRAILING_WINDOWS,
    VERTICAL_CHANNELS,
    FeatureExtractor,
    make_extractor,
    raw_record_template,
    rotation_from_euler,
    wrap_angle,
)
from quadwind_trl.envs import QuadWindEnv, make_scenarios
from quadwind_trl.envs.rotations import quat_from_euler, quat_to_rotmat
from quadwind_trl.envs.sensors import CHANNEL_NAMES, unpack_channels
from quadwind_trl.keys import MEAS_KEY

MASS = 2.59
G = 9.81


def random_record(n: int, t_len: int, seed: int = 0) -> dict[str, torch.Tensor | TensorDict]:
    """Plausible-range random raw records ``{key: [n, T, ...]}``, the sensors' named entries
    nested under ``"meas"`` (values need not be physical)."""
    gen = torch.Generator().manual_seed(seed)
    rec = dict(raw_record_template(n, t_len).apply(lambda z: torch.randn(z.shape, generator=gen)).items())
    attitude, accel = rec[MEAS_KEY]["attitude"], rec[MEAS_KEY]["accel"]
    attitude[..., 2] = wrap_angle(4 * attitude[..., 2])  # yaw
    accel[..., 2] += G  # body z
    rec["cmd_wrench"][..., 0] = MASS * G + rec["cmd_wrench"][..., 0]
    rec["ref_pos"] = torch.cumsum(rec["ref_pos"], 1)
    rec["ref_yaw"] = torch.cumsum(0.3 * rec["ref_yaw"], 1)  # unwrapped, drifts past +-pi
    rec["tilt_saturated"] = rec["tilt_saturated"] > 1.0
    return rec


def tick(rec: dict, rows, t: int) -> dict:
    """One tick laid out as the env emits it: contiguous ``[batch, C]`` tensors."""
    return {k: v[rows, t].clone() for k, v in rec.items()}


@pytest.mark.parametrize("yaw_mode", ["ref_relative", "wrapped"])
def test_channel_counts_and_names(yaw_mode):
    h = FeatureExtractor("horizontal", yaw_mode=yaw_mode)
    v = FeatureExtractor("vertical", yaw_mode=yaw_mode)
    assert h.num_channels == 48 and len(set(h.channels)) == 48
    assert v.num_channels == 22 and len(set(v.channels)) == 22
    assert h.channels[:13] == v.channels[:13]  # the shared kinematic block
    yaw = "yaw_err" if yaw_mode == "ref_relative" else "yaw"
    assert h.channels[9] == yaw and v.channels[9] == yaw
    assert h.channels[13:17] == ("u_T", "tau_x", "tau_y", "tau_z")
    assert h.channels[20:26] == ("aero_N", "aero_E", "aero_U", "aero_horiz", "tilt_cmd", "tilt_sat")
    assert h.channels[26:37] == tuple(f"avg100_{s}" for s in TRAILING_SIGNALS)
    assert h.channels[37:] == tuple(f"avg300_{s}" for s in TRAILING_SIGNALS)
    assert len(TRAILING_SIGNALS) == 11
    assert v.channels[13:] == ("dX", "dY", "dZ", "vx_ref", "vy_ref", "vz_ref", "ax_ref", "ay_ref", "az_ref")
    assert HORIZONTAL_CHANNELS == FeatureExtractor("horizontal").channels
    assert VERTICAL_CHANNELS == FeatureExtractor("vertical").channels
    assert set(h.raw_keys) | set(v.raw_keys) == set(RAW_RECORD_KEYS)
    rec = random_record(3, 4)
    for fx in (h, v):
        assert fx.scan(rec).shape == (3, 4, fx.num_channels)


def test_bad_schema_fails_early():
    with pytest.raises(ValueError, match="schema"):
        FeatureExtractor("diagonal")
    with pytest.raises(ValueError, match="yaw_mode"):
        FeatureExtractor("horizontal", yaw_mode="sin")


@pytest.mark.parametrize("schema, windows", [("horizontal", None), ("vertical", None), ("vertical", (100, 300))])
def test_online_equals_offline_bitwise(schema, windows):
    """Per-tick ``step`` calls (same batch, one flight per batch, and a batch whose rows restart
    at different ticks) give exactly the offline ``scan`` features."""
    n, t_len = 4, 650  # longer than the 300-sample trailing window
    rec = random_record(n, t_len, seed=1)
    fx = make_extractor(schema, windows=windows)
    offline = fx.scan(rec)

    # same batch, tick by tick
    state = fx.init_state(n)
    rows = []
    for t in range(t_len):
        state, f = fx.step(state, tick(rec, slice(None), t))
        rows.append(f)
    assert torch.equal(torch.stack(rows, 1), offline)

    # one flight at a time (batch of 1)
    for i in (0, 3):
        state = fx.init_state(1)
        out = []
        for t in range(t_len):
            state, f = fx.step(state, tick(rec, slice(i, i + 1), t))
            out.append(f)
        assert torch.equal(torch.cat(out), offline[i])

    # staggered: row 1 flies 123 ticks of another flight, is reset, then flies flight 2
    other = random_record(2, 123, seed=7)
    state = fx.init_state(2)
    for t in range(123):
        state, _ = fx.step(state, {k: torch.stack((rec[k][0, t], other[k][1, t])) for k in rec})
    state = fx.reset_rows(state, torch.tensor([False, True]))
    out = []
    for t in range(t_len - 123):
        state, f = fx.step(state, {k: torch.stack((rec[k][0, t + 123], rec[k][2, t])) for k in rec})
        out.append(f)
    out = torch.stack(out, 1)
    assert torch.equal(out[1], offline[2, : t_len - 123])
    assert torch.equal(out[0], offline[0, 123:])


def test_step_is_pure():
    fx = make_extractor("horizontal")
    rec = random_record(2, 5)
    state = fx.init_state(2)
    state, _ = fx.step(state, tick(rec, slice(None), 0))
    snapshot = {k: (v.clone() if torch.is_tensor(v) else v) for k, v in state.items()}
    record = tick(rec, slice(None), 1)
    kept = {k: v.clone() for k, v in record.items()}
    new, f1 = fx.step(state, record)
    _, f2 = fx.step(state, record)  # the old state is still usable
    assert torch.equal(f1, f2)
    for k, v in snapshot.items():
        if torch.is_tensor(v):
            assert torch.equal(state[k], v)
    kept = TensorDict(kept)
    for k, v in TensorDict(record).items(include_nested=True, leaves_only=True):  # the sensors' nested entries too
        assert torch.equal(v, kept[k]), k
    assert new is not state


def test_rotation_matches_simulator_convention():
    gen = torch.Generator().manual_seed(3)
    angles = (torch.rand(50, 3, generator=gen) - 0.5) * torch.tensor([2.0, 1.4, 6.2])
    r = rotation_from_euler(*angles.unbind(-1))
    mine = torch.stack([torch.stack(row, -1) for row in r], -2)
    ref = quat_to_rotmat(quat_from_euler(*angles.unbind(-1)))
    assert torch.allclose(mine, ref, atol=1e-6)


def hover_tick(roll, pitch, yaw, drag_world=(0.0, 0.0, 0.0), yaw_ref=None) -> dict:
    """Exact sensors of a vehicle holding position (zero acceleration) at the given attitude
    against a world-frame aerodynamic force ``drag_world`` (N): thrust along body z balances
    gravity and the drag's component along it; the accelerometer reads (thrust + drag) / m."""
    n = roll.shape[0]
    rot = quat_to_rotmat(quat_from_euler(roll, pitch, yaw))
    drag = torch.tensor(drag_world).expand(n, 3)
    b3 = rot[..., :, 2]
    # no lateral balance needed here: the residual is exact whatever the acceleration
    thrust = MASS * G / b3[..., 2]
    force_world = thrust[:, None] * b3 + drag
    sf_body = (rot.transpose(-1, -2) @ force_world.unsqueeze(-1)).squeeze(-1) / MASS
    meas = unpack_channels(torch.zeros(n, len(CHANNEL_NAMES)))
    meas["attitude"] = torch.stack((roll, pitch, yaw), -1)
    meas["accel"] = sf_body
    cmd = torch.zeros(n, 4)
    cmd[:, 0] = thrust
    return {
        MEAS_KEY: meas,
        "cmd_wrench": cmd,
        "tilt_cmd": torch.zeros(n, 1),
        "tilt_saturated": torch.zeros(n, 1, dtype=torch.bool),
        "ref_pos": torch.zeros(n, 3),
        "ref_yaw": (yaw if yaw_ref is None else yaw_ref).unsqueeze(-1),
    }


def test_aero_residual_hand_values():
    fx = make_extractor("horizontal")
    ch = {name: i for i, name in enumerate(fx.channels)}
    z = torch.zeros(4)
    yaw = torch.tensor([0.0, 1.0, -2.5, 3.1])
    # level hover in still air, exact sensors: residual 0, kinematic acceleration 0
    _, f = fx.step(fx.init_state(4), hover_tick(z, z, yaw))
    for name in ("aero_N", "aero_E", "aero_U", "aero_horiz", "acc_bx", "acc_by", "acc_bz"):
        assert f[:, ch[name]].abs().max() < 1e-5, name
    assert torch.allclose(f[:, ch["u_T"]], torch.full((4,), MASS * G))
    assert torch.allclose(f[:, ch["sf_bz"]], torch.full((4,), G))
    # tilted, with a known aerodynamic force (east 0.8 N, north -1.5 N, up 0.3 N): read back
    roll = torch.tensor([0.1, -0.2, 0.3, 0.0])
    pitch = torch.tensor([0.05, 0.2, -0.1, 0.25])
    _, f = fx.step(fx.init_state(4), hover_tick(roll, pitch, yaw, drag_world=(0.8, -1.5, 0.3)))
    assert torch.allclose(f[:, ch["aero_E"]], torch.full((4,), 0.8), atol=1e-4)
    assert torch.allclose(f[:, ch["aero_N"]], torch.full((4,), -1.5), atol=1e-4)
    assert torch.allclose(f[:, ch["aero_U"]], torch.full((4,), 0.3), atol=1e-4)
    assert torch.allclose(f[:, ch["aero_horiz"]], torch.full((4,), math.hypot(0.8, 1.5)), atol=1e-4)
    # world horizontal acceleration = aero / m here (thrust's horizontal part is not balanced):
    # check the kinematic body acceleration against the simulator's rotation instead
    rot = quat_to_rotmat(quat_from_euler(roll, pitch, yaw))
    sf = torch.stack([f[:, ch[c]] for c in ("sf_bx", "sf_by", "sf_bz")], -1)
    acc_world = (rot @ sf.unsqueeze(-1)).squeeze(-1) - torch.tensor([0.0, 0.0, G])
    acc_body = (rot.transpose(-1, -2) @ acc_world.unsqueeze(-1)).squeeze(-1)
    got = torch.stack([f[:, ch[c]] for c in ("acc_bx", "acc_by", "acc_bz")], -1)
    assert torch.allclose(got, acc_body, atol=1e-5)
    assert torch.allclose(f[:, ch["avg100_acc_N"]], acc_world[:, 1], atol=1e-5)
    assert torch.allclose(f[:, ch["avg300_acc_E"]], acc_world[:, 0], atol=1e-5)


def test_yaw_channel_wraps_relative_to_reference():
    fx = make_extractor("horizontal")
    raw = make_extractor("horizontal", yaw_mode="wrapped")
    z = torch.zeros(3)
    yaw = torch.tensor([math.pi - 0.01, -math.pi + 0.01, 0.5])
    yaw_ref = torch.tensor([-math.pi + 0.01 + 4 * math.pi, math.pi - 0.02, 0.5 - 2 * math.pi])
    _, f = fx.step(fx.init_state(3), hover_tick(z, z, yaw, yaw_ref=yaw_ref))
    assert torch.allclose(f[:, 9], torch.tensor([-0.02, 0.03, 0.0]), atol=1e-5)
    _, f = raw.step(raw.init_state(3), hover_tick(z, z, yaw, yaw_ref=yaw_ref))
    assert torch.allclose(f[:, 9], yaw, atol=1e-6)


@pytest.mark.parametrize("windows", [(100, 300), (7, 100, 300, 450)])
def test_trailing_means_of_a_ramp(windows):
    """Commanded thrust ramps 0, 1, 2, ...: the trailing mean at tick k is the mean of the last
    min(k + 1, W) values (expanding at the start), for any set of windows."""
    fx = make_extractor("horizontal", windows=windows)
    ch = {name: i for i, name in enumerate(fx.channels)}
    t_len = 700
    rec = random_record(1, t_len)
    rec["cmd_wrench"][..., 0] = torch.arange(t_len, dtype=torch.float32)
    f = fx.scan(rec)[0]
    k = torch.arange(t_len, dtype=torch.float64)
    for w in windows:
        expect = torch.where(k < w, k / 2, k - (w - 1) / 2)
        assert torch.allclose(f[:, ch[f"avg{w}_u_T"]].double(), expect, atol=1e-4, rtol=0), w
    # a constant signal's trailing mean is that constant at every tick, incl. the first
    rec[MEAS_KEY]["gps_vel"][..., 1] = 4.25  # north
    f = fx.scan(rec)[0]
    for w in windows:
        assert torch.equal(f[:, ch[f"avg{w}_vel_N"]], torch.full((t_len,), 4.25))
    # the paper's two windows are the same numbers whatever other windows ride along
    if windows != TRAILING_WINDOWS:
        base = make_extractor("horizontal").scan(rec)[0]
        assert torch.equal(f[:, [ch[c] for c in HORIZONTAL_CHANNELS]], base)


def test_vertical_trailing_means():
    """The vertical schema's optional trailing means: a constant position error and a tilted
    thrust axis give their own values at every tick; the 22 paper channels are unchanged."""
    fx = make_extractor("vertical", windows=(5, 30))
    ch = {name: i for i, name in enumerate(fx.channels)}
    rec = random_record(2, 60)
    rec[MEAS_KEY]["gps_pos"][..., :2] = rec["ref_pos"][..., :2] + torch.tensor([0.5, -0.25])  # dX = 0.5 m east
    rec[MEAS_KEY]["attitude"][...] = torch.tensor([0.1, 0.0, 0.0])  # roll 0.1 rad, yaw 0 (nose east): leans south
    rec[MEAS_KEY]["accel"][...] = torch.tensor([0.0, 0.3, 9.8])  # body y specific force
    f = fx.scan(rec)
    for w in (5, 30):
        assert torch.allclose(f[..., ch[f"avg{w}_dX"]], torch.tensor(0.5), atol=1e-5)
        assert torch.allclose(f[..., ch[f"avg{w}_dY"]], torch.tensor(-0.25), atol=1e-5)
        assert torch.allclose(f[..., ch[f"avg{w}_tilt_N"]], torch.tensor(-math.sin(0.1)), atol=1e-6)
        assert torch.allclose(f[..., ch[f"avg{w}_tilt_E"]], torch.tensor(0.0), atol=1e-6)
        # body y rotated by the roll into the world: (0, 0.3 cos 0.1) in (E, N)
        assert torch.allclose(f[..., ch[f"avg{w}_sfp_N"]], torch.tensor(0.3 * math.cos(0.1)), atol=1e-5)
        assert torch.allclose(f[..., ch[f"avg{w}_sfp_E"]], torch.tensor(0.0), atol=1e-6)
    assert torch.equal(f[..., :22], make_extractor("vertical").scan(rec))


def test_extractor_from_an_estimators_channels():
    """A checkpoint's channel names say which extractor made them; names no extractor makes are
    refused, naming the difference."""
    fx = make_extractor("horizontal", windows=(100, 300, 1200))
    assert make_extractor("horizontal", channels=fx.channels) == fx
    assert make_extractor("horizontal", channels=HORIZONTAL_CHANNELS).windows == TRAILING_WINDOWS
    assert make_extractor("vertical", channels=VERTICAL_CHANNELS).channels == VERTICAL_CHANNELS
    with pytest.raises(ValueError, match=r"not the 'vertical' feature extractor's \(38.*unexpected"):
        make_extractor("vertical", channels=HORIZONTAL_CHANNELS)  # its avg100/avg300 names ask for 2 windows
    vfx = make_extractor("vertical", windows=(100, 300))
    assert make_extractor("vertical", channels=vfx.channels) == vfx and vfx.num_channels == 22 + 2 * 8
    assert make_extractor("horizontal", channels=HORIZONTAL_CHANNELS[:26]).windows == ()
    with pytest.raises(ValueError, match=r"missing \['avg300_u_T'\]"):
        make_extractor("horizontal", channels=HORIZONTAL_CHANNELS[:-1])
    for bad in ((300, 100), (0, 100), (100, 100), (100, 10**6)):
        with pytest.raises(ValueError, match=r"FeatureExtractor.windows=.*increasing integer sample counts"):
            make_extractor("horizontal", windows=bad)


def test_vertical_reference_differences_and_errors():
    fx = make_extractor("vertical")
    ch = {name: i for i, name in enumerate(fx.channels)}
    t_len = 40
    rec = random_record(1, t_len)
    t = torch.arange(t_len, dtype=torch.float32) * 0.1
    rec["ref_pos"] = torch.stack((2.0 * t, torch.zeros_like(t), 0.5 * 1.5 * t * t), -1)[None]  # vx=2, az=1.5
    f = fx.scan(rec)[0]
    assert torch.all(f[0, 13 + 3 :] == 0)  # first sample: at rest
    assert torch.allclose(f[1:, ch["vx_ref"]], torch.full((t_len - 1,), 2.0), atol=1e-4)
    assert torch.allclose(f[2:, ch["az_ref"]], torch.full((t_len - 2,), 1.5), atol=2e-3)
    assert torch.allclose(f[1:, ch["vz_ref"]], 1.5 * (t[1:] - 0.05), atol=1e-3)  # backward difference
    meas = rec[MEAS_KEY][0]
    assert torch.equal(f[:, ch["dX"]], meas["gps_pos"][:, 0] - rec["ref_pos"][0, :, 0])
    assert torch.equal(f[:, ch["dZ"]], meas["baro_alt"][:, 0] - rec["ref_pos"][0, :, 2])
    assert torch.equal(f[:, ch["alt"]], meas["baro_alt"][:, 0])
    assert torch.equal(f[:, ch["vel_N"]], meas["gps_vel"][:, 1])


def test_real_hover_in_still_air_has_no_aero_residual():
    """The simulator, exact sensors, still air, airborne start at the loiter pattern (hover,
    speed ramping from zero): the residual is ~0 while the vehicle is still slow."""
    cfg = EnvConfig(sensors=SensorConfig(enabled=False), turbulence=TurbulenceConfig(enabled=False))
    env = QuadWindEnv(cfg, batch_size=[1])
    td = env.reset(scenario=make_scenarios(1, traj_id="loiter_circle_h", altitude_m=50.0, start_step=-1))
    fx = make_extractor("horizontal")
    ch = {name: i for i, name in enumerate(fx.channels)}
    state = fx.init_state(1)
    for i in range(31):
        if i % 10 == 0:
            state, f = fx.step(state, {k: td[k] for k in fx.raw_keys})
            # the reset observation of an airborne start carries the PD wrench as its command
            for name in ("aero_N", "aero_E", "aero_U"):
                assert abs(float(f[0, ch[name]])) < 0.05, (i, name)
        td["action"] = torch.zeros(1, 4)
        td = env.step(td)["next"]
