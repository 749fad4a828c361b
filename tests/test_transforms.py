"""The wind-aware transform stack: specs, one feature code path online/offline, per-row resets,
the frozen estimator, the ZeroInputs ablations and the zero-action = PD invariant."""
from __future__ import annotations

import math

from dataclasses import replace

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Unbounded
from torchrl.envs import Compose, Transform, TransformedEnv
from torchrl.envs.utils import check_env_specs

from quadwind_trl.config import EnvConfig, TrajectoryConfig
from quadwind_trl.estimator.features import make_extractor
from quadwind_trl.envs import QuadWindEnv, ScenarioSampler, make_scenarios
from quadwind_trl.envs.runner import fly
from quadwind_trl.envs.sensors import pack_channels
from quadwind_trl.estimator.ema import EMAConfig, ema_init, ema_scan, ema_step
from quadwind_trl.keys import MEAS_KEY, OBSERVATION_CHANNELS, OBSERVATION_DIM, WIND_CHANNELS, WIND_INDICES
from quadwind_trl.estimator import untrained_estimator
from quadwind_trl.rl.envs import make_env, vecnorm, wind_estimate
from quadwind_trl.transforms import EpisodeControl, PolicyObservation, WindEstimate, ZeroInputs

RAW = (MEAS_KEY, "cmd_wrench", "tilt_cmd", "tilt_saturated", "ref_pos", "ref_yaw")


def short_config(w_z: float = 1.0) -> EnvConfig:
    """Full sensors and turbulence, short flights at low altitude (tests must be quick)."""
    cfg = EnvConfig(trajectories=TrajectoryConfig(horizontal_duration_s=4.0, vertical_top_m=10.0, vertical_hold_s=1.0))
    return replace(cfg, reward=replace(cfg.reward, w_z=w_z))


def scenarios(n: int, traj=("figure8_h", "lawnmower_h", "racetrack_h"), altitude=6.0, **kw):
    traj = [traj[i % len(traj)] for i in range(n)]
    return make_scenarios(
        n, traj_id=traj, altitude_m=altitude, wind_speed_ref_m_s=[6.0 + i for i in range(n)], wind_dir_deg=[40.0 * i for i in range(n)],
        turb_intensity=0.15, turb_seed=[11 + i for i in range(n)], sensor_seed=[21 + i for i in range(n)], **kw,
    )  # fmt: skip


@pytest.fixture(scope="module")
def bundle():
    return untrained_estimator("horizontal", seed=0, config=short_config())


def latest_features(west: WindEstimate) -> torch.Tensor:
    """``[N, C]``: every row's newest sample in ``WindEstimate``'s feature ring."""
    return west.ring.windows(torch.arange(west.ring.n))[:, -1]


class LatestFeatures(Transform):
    """Test probe: logs ``WindEstimate``'s newest ring sample as ``"features"`` at every step."""

    def __init__(self, west: WindEstimate):
        super().__init__(in_keys=[], out_keys=["features"])
        self.west = west

    def _call(self, td):
        td.set("features", latest_features(self.west))
        return td

    def _reset(self, tensordict, tensordict_reset):
        return self._call(tensordict_reset)

    def transform_observation_spec(self, spec):
        spec["features"] = Unbounded(shape=(*spec.shape, self.west.ring.extractor.num_channels), device=spec.device)
        return spec


def test_observation_layout():
    assert OBSERVATION_DIM == 23 and len(OBSERVATION_CHANNELS) == 23
    assert WIND_INDICES == (13, 14)
    feats = make_extractor("horizontal").channels
    assert OBSERVATION_CHANNELS[0] == feats[0] and OBSERVATION_CHANNELS[3:13] == feats[3:13]
    assert OBSERVATION_CHANNELS[1:3] == ("vel_fwd", "vel_left")
    assert OBSERVATION_CHANNELS[13:] == (
        "wind_fwd", "wind_left", "err_fwd", "err_left", "err_U", "pd_thrust_over_weight", "ff_T", "ff_x", "ff_y", "ff_z"
    )


def test_heading_frame_by_hand():
    from quadwind_trl.transforms.observation import to_heading_frame

    # facing north (yaw 90 deg): an eastward vector points to the right (left = -1)
    f, l = to_heading_frame(torch.tensor(1.0), torch.tensor(0.0), torch.tensor(math.pi / 2))
    assert abs(f.item()) < 1e-6 and abs(l.item() + 1.0) < 1e-6
    # facing south-west (yaw -135 deg): a north-east vector points backwards
    f, l = to_heading_frame(torch.tensor(1.0), torch.tensor(1.0), torch.tensor(-3 * math.pi / 4))
    assert abs(f.item() + math.sqrt(2)) < 1e-6 and abs(l.item()) < 1e-6


@pytest.mark.parametrize("wind_input", ["estimate", "zero", "truth"])
def test_transformed_env_passes_check_env_specs(bundle, wind_input):
    env = make_env("horizontal", bundle, 3, wind_input=wind_input, config=short_config(), desync_steps=5, compile_step=False)
    check_env_specs(env)
    assert env.observation_spec["observation"].shape == (3, OBSERVATION_DIM)
    assert env.observation_spec["wind_hat"].shape == (3, 2)


def test_vertical_env_and_schema_mismatch(bundle):
    vb = untrained_estimator("vertical", config=short_config(0.5))
    env = make_env("vertical", vb, 2, config=short_config(0.5), compile_step=False)
    check_env_specs(env)
    with pytest.raises(ValueError, match="schema"):
        make_env("vertical", bundle, 2, compile_step=False)


def test_each_transform_alone(bundle):
    """WindEstimate (estimate, truth), PolicyObservation and ZeroInputs on a bare env."""
    cfg = short_config()
    for transforms in (
        [WindEstimate(bundle, config=cfg)],
        [WindEstimate(source="truth", config=cfg), PolicyObservation(cfg), ZeroInputs(WIND_CHANNELS)],
        [WindEstimate(source="truth", config=cfg), ZeroInputs(None, in_key="wind_hat")],
        [EpisodeControl(3)],
    ):
        env = TransformedEnv(QuadWindEnv(cfg, batch_size=[2]), Compose(*transforms))
        check_env_specs(env)


@torch.no_grad()
def test_online_features_and_estimates_equal_offline(bundle):
    """Flying through WindEstimate gives, at every 10 Hz tick, exactly (bitwise) the offline
    ``scan`` features of the same flight's record in its ring; the estimator input windows are
    the offline windows (left-padded by repeating the first sample) and ``wind_hat`` is the EMA of
    the estimator's outputs on them (to 1e-5: the estimator batches rows differently)."""
    cfg = short_config()
    n = 3
    west = WindEstimate(bundle, config=cfg)
    env = TransformedEnv(QuadWindEnv(cfg, batch_size=[n]), Compose(west, LatestFeatures(west)))
    res = fly(env, scenarios(n), log_keys=RAW + ("step", "features", "wind_hat"))
    log = res.log
    valid = log["valid"]
    assert bool(valid.all()), "same-length flights expected"
    assert log.batch_size[1] > 60  # longer than the estimator window
    fx = make_extractor("horizontal", cfg)
    offline = fx.scan({k: log[k] for k in fx.raw_keys})
    assert torch.equal(log["features"], offline)

    # the estimator's windows and the filtered estimate
    t_len = offline.shape[1]
    idx = torch.arange(t_len)[:, None] + torch.arange(-59, 1)[None, :]  # [T, 60]
    padded = offline[:, idx.clamp_min(0)]  # left padding = the first sample repeated
    preds = bundle.predict(padded.reshape(n * t_len, 60, -1)).reshape(n, t_len, 2)
    expected = ema_scan(preds, EMAConfig(dt_s=cfg.timing.log_dt_s))
    torch.testing.assert_close(log["wind_hat"], expected, atol=1e-5, rtol=1e-5)


@torch.no_grad()
def test_online_features_equal_offline_with_staggered_rows(bundle):
    """A row restarted between ticks ticks on other control steps than the rest: every row's
    online features still equal (bitwise) the offline scan of its own flight record."""
    cfg = short_config()
    fx = make_extractor("horizontal", cfg)
    west = WindEstimate(bundle, config=cfg)
    env = TransformedEnv(QuadWindEnv(cfg, batch_size=[3]), west)
    rec = {i: [] for i in range(3)}

    def log(td, rows):
        feats = latest_features(west)
        for i in rows:
            if int(td["step"][i]) % 10 == 0:
                row = td[i].select(*fx.raw_keys).clone()
                row["features"] = feats[i].clone()
                rec[i].append(row)

    td = env.reset(scenario=scenarios(3))
    log(td, range(3))
    for k in range(425):
        if k == 25:  # restart row 1 (on another trajectory and wind) at a non-tick step
            td["_reset"] = torch.tensor([[False], [True], [False]])
            td = env.reset(td, scenario=scenarios(3, traj=("cloverleaf_h",), start_step=0))
            rec[1] = []
            log(td, [1])
        td["action"] = torch.full((3, 4), 0.2)
        td = env.step(td)["next"]
        log(td, range(3))
    for i in range(3):
        flight = torch.stack(rec[i])
        offline = fx.scan({k: flight[k].unsqueeze(0) for k in fx.raw_keys})[0]
        assert torch.equal(flight["features"], offline), i
    assert len(rec[1]) == 41 and len(rec[0]) == 43


def test_history_and_ema_reset_only_masked_rows(bundle):
    cfg = short_config()
    west = WindEstimate(bundle, config=cfg)
    env = TransformedEnv(QuadWindEnv(cfg, batch_size=[3]), west)
    td = env.reset(scenario=scenarios(3))
    for _ in range(35):  # 3 more ticks after the first
        td["action"] = torch.zeros(3, 4)
        td = env.step(td)["next"]
    ring = west.ring
    before = {
        "buf": ring.buf.clone(), "ptr": ring.ptr.clone(), "count": ring.count.clone(),
        "sum": ring.fx_state["sums"][:, -1].clone(),
        "ema": {k: v.clone() for k, v in west.ema_state.items()}, "value": west.value.clone(),
    }  # fmt: skip
    assert before["count"].tolist() == [4, 4, 4]
    mask = torch.tensor([False, True, False])
    td["_reset"] = mask.unsqueeze(-1)  # as a collector resets: the current data plus the mask
    out = env.reset(td, scenario=scenarios(3))
    keep = ~mask
    assert torch.equal(ring.buf[keep], before["buf"][keep])
    assert torch.equal(ring.ptr[keep], before["ptr"][keep]) and torch.equal(ring.count[keep], before["count"][keep])
    assert torch.equal(ring.fx_state["sums"][:, -1][keep], before["sum"][keep])
    for k, v in before["ema"].items():
        assert torch.equal(west.ema_state[k][keep], v[keep])
    assert torch.equal(west.value[keep], before["value"][keep])
    assert torch.equal(out["wind_hat"][keep], before["value"][keep])
    # the reset row restarted: one sample, its window is that sample repeated, EMA = first estimate
    assert ring.count.tolist() == [4, 1, 4]
    w = ring.windows(torch.tensor([1]))[0]
    assert torch.equal(w, w[-1].expand_as(w))
    first = bundle.predict(west.ring.windows(torch.tensor([1])))
    torch.testing.assert_close(west.value[1:2], first)
    assert bool(west.ema_state["started"][1])


def test_estimator_is_frozen_and_outside_parameters(bundle):
    env = make_env("horizontal", bundle, 2, config=short_config(), compile_step=False)
    west = wind_estimate(env)
    assert list(west.parameters()) == [] and list(env.transform.parameters()) == []
    assert not any("gru" in k or "head" in k for k in env.state_dict())
    assert not bundle.model.training
    assert all(not p.requires_grad for p in bundle.model.parameters())


def test_wind_zero_zeroes_exactly_the_wind_inputs(bundle):
    """Same scenarios, same (zero) actions: the ablation env's observation differs from the
    wind-aware one in channels 13, 14 only, which are exactly 0 (after normalisation)."""
    cfg = short_config()
    envs = {w: make_env("horizontal", bundle, 3, wind_input=w, config=cfg, compile_step=False) for w in ("estimate", "zero")}
    obs = {}
    for w, env in envs.items():
        td = env.reset(scenario=scenarios(3))
        rows = [td["observation"]]
        for _ in range(30):
            td["action"] = torch.zeros(3, 4)
            td = env.step(td)["next"]
            rows.append(td["observation"])
        obs[w] = torch.stack(rows, 1)
    a, z = obs["estimate"], obs["zero"]
    others = [i for i in range(OBSERVATION_DIM) if i not in WIND_INDICES]
    assert torch.equal(z[..., list(WIND_INDICES)], torch.zeros_like(z[..., :2]))
    assert torch.equal(z[..., others], a[..., others])
    assert a[..., list(WIND_INDICES)].abs().sum() > 0


def test_raw_observation_matches_sensors_and_features(bundle):
    """Before normalisation: the kinematic block equals the estimator features' (at ticks), the
    wind block is wind_hat, and the controller channels are the env's entries."""
    cfg = short_config()
    west = WindEstimate(bundle, config=cfg, out_key="wind_estimate")  # its ring holds the features
    env = TransformedEnv(QuadWindEnv(cfg, batch_size=[2]), Compose(
        west, WindEstimate(source="truth", config=cfg), PolicyObservation(cfg)))
    td = env.reset(scenario=scenarios(2))
    for _ in range(20):
        td["action"] = torch.full((2, 4), 0.3)
        td = env.step(td)["next"]
    from quadwind_trl.transforms.observation import to_heading_frame

    obs, feats = td["observation"], latest_features(west)
    _, _, yaw = td[MEAS_KEY, "attitude"].unbind(-1)
    # step 20 is a tick: the kinematic block is the features', horizontal velocity in the heading frame
    assert torch.equal(obs[:, 0], feats[:, 0]) and torch.equal(obs[:, 3:13], feats[:, 3:13])
    assert torch.equal(obs[:, 1:3], torch.stack(to_heading_frame(feats[:, 1], feats[:, 2], yaw), -1))
    mw = td["truth", "mean_wind"]
    assert torch.equal(td["wind_hat"], torch.stack((mw[:, 1], mw[:, 0]), -1))
    assert torch.equal(obs[:, 13:15], torch.stack(to_heading_frame(mw[:, 0], mw[:, 1], yaw), -1))
    err = td["pos_error"]
    assert torch.equal(obs[:, 15:17], torch.stack(to_heading_frame(err[:, 0], err[:, 1], yaw), -1))
    assert torch.equal(obs[:, 17], err[:, 2])
    torch.testing.assert_close(obs[:, 18], td["pd_wrench"][:, 0] / (cfg.vehicle.mass_kg * 9.81))
    torch.testing.assert_close(obs[:, 19:], td["ff_wrench"] / torch.tensor(cfg.residual.action_scale))


def test_zero_policy_reproduces_pd(bundle):
    """The full training stack with a policy whose output is forced to zero flies exactly the
    PD baseline of the bare env on the same scenarios (runner.fly, bit for bit)."""
    from quadwind_trl.rl.config import PPOConfig
    from quadwind_trl.rl.policy import build_actor_critic

    cfg = short_config()
    sc = scenarios(3, start_step=-1)  # airborne at the pattern start (quicker)
    pd = fly(QuadWindEnv(cfg, batch_size=[3]), sc)
    actor, _ = build_actor_critic(PPOConfig(hidden=(32, 32)))
    last = actor.module[0].module[0][-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()
    env = make_env("horizontal", bundle, 3, config=cfg, compile_step=False)
    rl = fly(env, sc, policy=actor)
    assert torch.equal(rl.rmse_xy, pd.rmse_xy) and torch.equal(rl.rmse_z, pd.rmse_z)
    assert torch.equal(pack_channels(rl.log[MEAS_KEY]), pack_channels(pd.log[MEAS_KEY]))
    assert torch.equal(rl.log["ff_wrench"], torch.zeros_like(rl.log["ff_wrench"]))


def test_running_norm_never_returns_nan():
    """VecNormV2's variance E[x^2] - E[x]^2 can come out below 0 by cancellation on a constant
    channel, and its square root is then NaN; RunningObsNorm clamps it at 0 (scale = eps)."""
    from torchrl.envs import VecNormV2

    from quadwind_trl.transforms import RunningObsNorm

    x = torch.tensor([1.1, 2.0])
    loc = TensorDict({"observation": x}, [])
    var = TensorDict({"observation": x * x * torch.tensor([1 - 1e-7, 1.0])}, [])  # first: 1 ulp too small
    count = TensorDict({"observation": torch.tensor(5)}, [])
    data = TensorDict({"observation": x.clone()}, [])
    plain = VecNormV2(in_keys=["observation"], decay=1.0)._norm(data, loc, var, count)["observation"]
    fixed = RunningObsNorm(in_keys=["observation"], decay=1.0)._norm(data, loc, var, count)["observation"]
    assert torch.isnan(plain[0])
    assert torch.equal(fixed, torch.zeros(2))


def test_vecnorm_pools_rows_and_freezes(bundle):
    env = make_env("horizontal", bundle, 4, config=short_config(), compile_step=False)
    vn = vecnorm(env)
    r = env.rollout(20, break_when_any_done=False)
    assert torch.isfinite(r["observation"]).all() and torch.isfinite(r["next", "observation"]).all()
    assert vn.loc["observation"].shape == (OBSERVATION_DIM,)  # one statistics set for all sub-envs
    vn.freeze()
    loc = vn.loc["observation"].clone()
    env.rollout(5, break_when_any_done=False)
    assert torch.equal(loc, vn.loc["observation"])
    state = {k: v for k, v in vn.state_dict().items()}
    env2 = make_env("horizontal", bundle, 4, config=short_config(), vecnorm_state=state, compile_step=False)
    assert vecnorm(env2).frozen and torch.allclose(vecnorm(env2).loc["observation"], loc)


def test_running_norm_counts_the_restarting_rows_of_a_partial_reset_once():
    """A partial reset adds the first observations of the rows that restart, and only those, to
    the statistics (VecNormV2 added every row: those that go on a second time, or as zeros behind
    a ParallelEnv)."""
    from quadwind_trl.transforms import RunningObsNorm

    norm = RunningObsNorm(in_keys=["observation"], decay=1.0, reduce_batch_dims=True)
    first = TensorDict({"observation": torch.tensor([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]])}, [3])
    norm._reset(None, first.clone())  # a full reset: every row
    restart = TensorDict({"_reset": torch.tensor([[False], [True], [False]])}, [3])
    again = TensorDict({"observation": torch.tensor([[0.0, 0.0], [9.0, 12.0], [0.0, 0.0]])}, [3])
    out = norm._reset(restart, again)
    assert int(norm._count["observation"]) == 4
    torch.testing.assert_close(norm.loc["observation"], torch.tensor([(1 + 3 + 5 + 9) / 4, (2 + 4 + 6 + 12) / 4]))
    assert out["observation"].shape == (3, 2)  # every row normalised, with the updated statistics
    norm._reset(TensorDict({"_reset": torch.zeros(3, 1, dtype=torch.bool)}, [3]), again.clone())
    assert int(norm._count["observation"]) == 4


def test_collection_workers_fly_the_rows_of_one_env(bundle):
    """build_env(workers=2): two processes of 2 rows each with the row-wise transforms, the
    normalisation here, fly the episodes of the one-process env: the same rewards (the tracking
    error of each row's physics) and ends (first-episode truncations, a curriculum switch) bit for
    bit; observations to float rounding (the estimator's matrix products depend on the batch size
    in their last bits). The workers return only what the policy and the trainer read."""
    from quadwind_trl.rl.envs import RLEnvSpec, build_env, estimator_seconds, set_trajectories

    spec = RLEnvSpec("horizontal", num_envs=4, config=short_config(), compile_step=False, desync_steps=30, seed=3)
    flown = []
    for workers in (1, 2):
        env = build_env(spec, bundle, workers=workers)
        try:
            td, record = env.reset(), []
            for k in range(50):
                if k == 35:
                    set_trajectories(env, ("racetrack_h",), truncate=True)
                td["action"] = torch.full((*env.batch_size, 4), 0.05 * (k % 3 - 1))
                step, td = env.step_and_maybe_reset(td)
                record.append(step["next"].select("observation", "reward", "done", "truncated", "episode_reward",
                                                  "step_count").reshape(4).clone())
            assert estimator_seconds(env) > 0
            flown.append(torch.stack(record, 1))
        finally:
            env.close()
    one, two = flown
    assert int(one["truncated"][:, :35].sum()) >= 3 and bool(one["truncated"][:, 35].all())  # desync, then the switch
    for key in ("reward", "done", "truncated", "episode_reward", "step_count"):
        assert torch.equal(one[key], two[key]), key
    torch.testing.assert_close(one["observation"], two["observation"], rtol=0, atol=1e-5)
    with pytest.raises(ValueError, match=r"workers=3; allowed: >= 1 and dividing RLEnvSpec.num_envs=4"):
        build_env(spec, bundle, workers=3)


def test_episode_control_desyncs_first_episodes():
    cfg = short_config()
    env = TransformedEnv(QuadWindEnv(cfg, batch_size=[6], scenario_sampler=ScenarioSampler(start="pattern")),
                         EpisodeControl(desync_steps=50, seed=1))
    r = env.rollout(60, break_when_any_done=False)
    trunc = r["next", "truncated"].squeeze(-1)
    first = trunc.float().argmax(1) + 1
    assert bool(trunc.any(1).all())
    assert torch.equal(first, env.transform.limit) and bool((first <= 50).all()) and bool((first % 10 == 0).all())
    assert len(set(first.tolist())) > 1
    assert not bool(r["next", "terminated"].any())
    env.transform.request_truncation()
    td = env.rand_step(env.reset())
    assert bool(td["next", "truncated"].all())


class ConstantEstimator:
    """A second estimator, written against the WindEstimator interface only: always the same wind."""

    schema = "horizontal"
    window = 5

    def __init__(self, wind_ne: tuple[float, float], config: EnvConfig):
        self.channels = make_extractor("horizontal", config).channels
        self.wind = torch.tensor(wind_ne)

    def predict(self, windows: torch.Tensor) -> torch.Tensor:
        assert windows.shape[1:] == (self.window, len(self.channels))
        return self.wind.expand(windows.shape[0], 2)

    def to(self, device):
        self.wind = self.wind.to(device)
        return self


@torch.no_grad()
def test_a_new_estimator_class_drives_wind_estimate():
    """Any WindEstimator plugs into the env: its predictions (EMA-filtered; a constant passes the
    filter unchanged) become wind_hat, on its own window length; make_env sets the EMA tau."""
    from quadwind_trl.estimator import WindEstimator

    cfg = short_config()
    est = ConstantEstimator((3.0, -4.0), cfg)
    assert isinstance(est, WindEstimator)
    env = make_env("horizontal", est, 2, config=cfg, ema_tau_s=1.5, compile_step=False)
    check_env_specs(env)
    west = wind_estimate(env)
    assert west.ring.window == 5 and west.ema_config.tau_s == 1.5
    td = env.reset(scenario=scenarios(2))
    for _ in range(3):
        td["action"] = torch.zeros(2, 4)
        td = env.step(td)["next"]
        assert torch.equal(td["wind_hat"], est.wind.expand(2, 2))


def test_policy_ema_tau_s_falls_back_to_the_estimator_checkpoint(bundle):
    """Policies record the env's EMA tau; older ones trained with their estimator's."""
    from quadwind_trl.estimator import DEFAULT_TAU_S, load_estimator
    from quadwind_trl.manifest import CHECKPOINT_DIR
    from quadwind_trl.rl.envs import policy_env_settings
    from quadwind_trl.validation import load_checkpoint

    def policy_ema_tau_s(env_spec: dict, estimator) -> float:
        return policy_env_settings(env_spec, estimator)["ema_tau_s"]

    assert policy_ema_tau_s({"ema_tau_s": 2.0}, bundle) == 2.0
    assert policy_ema_tau_s({}, replace(bundle, ema_tau_s=4.5)) == 4.5
    assert policy_ema_tau_s({}, bundle) == DEFAULT_TAU_S  # no tau in the checkpoint
    assert make_env("horizontal", bundle, 1, config=short_config(), compile_step=False).transform[1].ema_config.tau_s == DEFAULT_TAU_S
    # the shipped policies trained behind the tau chosen on validation flights (docs/estimator.md);
    # the same spec without it (a checkpoint from before taus were recorded) takes the estimator's
    for regime, tau in (("horizontal", 30.0), ("vertical", 20.0)):
        spec = load_checkpoint(CHECKPOINT_DIR / f"policy_{regime}.pt", "policy")["env_spec"]
        assert policy_ema_tau_s(spec, load_estimator(regime)) == spec["ema_tau_s"] == tau
        older = {key: value for key, value in spec.items() if key != "ema_tau_s"}
        assert policy_ema_tau_s(older, replace(load_estimator(regime), ema_tau_s=7.0)) == 7.0
    with pytest.raises(ValueError, match="ema_tau_s"):
        make_env("horizontal", bundle, 1, ema_tau_s=-1.0, compile_step=False)
    with pytest.raises(TypeError, match="unknown settings"):
        make_env("horizontal", bundle, 1, ema_tau=3.0, compile_step=False)
    with pytest.raises(TypeError, match=r"not a WindEstimator \(missing \['window'"):
        WindEstimate(type("NoWindow", (), {"schema": "horizontal", "channels": (), "predict": None, "to": None})())


def queried_estimates(estimator, features: torch.Tensor, stride: int, log_dt_s: float) -> torch.Tensor:
    """The reference ``[N, ceil(T / stride), 2]``: at every ``stride``-th tick from the first, the
    estimator on that tick's windows of all rows at once (as the transform batches same-phase
    rows), EMA-filtered with ``dt`` = ``stride`` log intervals."""
    n, t_len, _ = features.shape
    state, cfg, out = ema_init(n, 2), EMAConfig(dt_s=log_dt_s * stride), []
    for t in range(0, t_len, stride):
        window = features[:, torch.arange(t - estimator.window + 1, t + 1).clamp_min(0)]  # left-padded
        state, value = ema_step(state, estimator.predict(window), cfg)
        out.append(value)
    return torch.stack(out, 1)


@torch.no_grad()
def test_estimate_every_s_queries_every_kth_tick_and_holds_in_between(bundle):
    """The default (every log tick) is what every recorded policy flew: ``wind_hat`` at each tick
    is bitwise the EMA (dt = 0.1 s) of the estimator on that tick's windows. Every 0.5 s: the same
    ring (fed every tick), the estimator a fifth as often, the EMA stepped with dt = 0.5 s at
    ticks 0, 5, 10, ... and its value held in between."""
    cfg = short_config()
    n = 3
    every_tick = WindEstimate(bundle, config=cfg)
    fifth = WindEstimate(bundle, config=cfg, every_s=0.5, out_key="wind_hat_5")
    assert (every_tick.stride, fifth.stride) == (1, 5) and every_tick.ema_config.dt_s == cfg.timing.log_dt_s
    env = TransformedEnv(QuadWindEnv(cfg, batch_size=[n]), Compose(every_tick, fifth, LatestFeatures(every_tick)))
    log = fly(env, scenarios(n), log_keys=("features", "wind_hat", "wind_hat_5")).log  # one row per 10 Hz tick
    ticks = log.batch_size[1]
    assert bool(log["valid"].all())
    assert torch.equal(log["wind_hat"], queried_estimates(bundle, log["features"], 1, cfg.timing.log_dt_s))
    held = log["wind_hat_5"]
    assert torch.equal(held[:, ::5], queried_estimates(bundle, log["features"], 5, cfg.timing.log_dt_s))
    assert torch.equal(held, held[:, ::5].repeat_interleave(5, dim=1)[:, :ticks])
    assert every_tick.estimator_calls == n * ticks and fifth.estimator_calls == n * math.ceil(ticks / 5)


@torch.no_grad()
def test_each_row_queries_on_its_own_episode_phase(bundle):
    """A row restarted between ticks queries at its reset tick and every 5th tick of its new
    episode after it; between its queries its ``wind_hat`` does not move at any control step."""
    cfg = short_config()
    west = WindEstimate(bundle, config=cfg, every_s=0.5)
    env = TransformedEnv(QuadWindEnv(cfg, batch_size=[3]), west)
    td = env.reset(scenario=scenarios(3))
    queries = 3  # every row's reset tick
    for step in range(300):
        if step == 25:  # restart row 1 at a non-tick step: its ticks now fall 5 control steps off the others'
            td["_reset"] = torch.tensor([[False], [True], [False]])
            td = env.reset(td, scenario=scenarios(3, traj=("cloverleaf_h",), start_step=0))
            queries += 1
            assert west.ring.count[1] == 1 and west.estimator_calls == queries
            torch.testing.assert_close(td["wind_hat"][1:2], bundle.predict(west.ring.windows(torch.tensor([1]))))
        before = td["wind_hat"].clone()
        count = west.ring.count.clone()
        td["action"] = torch.zeros(3, 4)
        td = env.step(td)["next"]
        due = (west.ring.count != count) & ((west.ring.count - 1) % 5 == 0)
        queries += int(due.sum())
        moved = (td["wind_hat"] != before).any(-1)
        assert torch.equal(moved, due), step  # a query moves the EMA, nothing else does
    assert west.estimator_calls == queries
    assert west.ring.count.tolist() == [31, 28, 31]


def test_estimate_every_s_is_validated_recorded_and_defaults_for_old_policies(bundle):
    """A whole multiple of the log interval, named in the error; policies record it in their env
    spec, and those saved before it existed fly with every tick (0.1 s)."""
    from quadwind_trl.manifest import CHECKPOINT_DIR
    from quadwind_trl.rl.envs import RLEnvSpec, policy_env_settings, recipe_estimate_every_s
    from quadwind_trl.rl.policy import spec_to_dict
    from quadwind_trl.validation import load_checkpoint

    for bad in (0, -0.5, 0.15, 0.05, float("nan"), "0.5"):
        with pytest.raises(ValueError, match=r"RLEnvSpec\.estimate_every_s=.* allowed: a positive whole multiple of the log interval 0\.1 s"):
            make_env("horizontal", bundle, 1, estimate_every_s=bad, compile_step=False)
    with pytest.raises(ValueError, match=r"WindEstimate\.every_s=0\.25 s"):
        WindEstimate(bundle, config=short_config(), every_s=0.25)
    assert wind_estimate(make_env("horizontal", bundle, 1, config=short_config(), estimate_every_s=1.0,
                                  compile_step=False)).stride == 10
    recorded = spec_to_dict(RLEnvSpec(estimate_every_s=0.5))
    assert policy_env_settings(recorded, bundle)["estimate_every_s"] == 0.5
    older = {key: value for key, value in recorded.items() if key != "estimate_every_s"}
    assert policy_env_settings(older, bundle)["estimate_every_s"] == 0.1 == RLEnvSpec().estimate_every_s
    # the PPO recipes' default: the largest whole multiple of the log interval at or below tau / 30
    for tau, every in ((30.0, 1.0), (20.0, 0.6), (3.0, 0.1), (0.0, 0.1), (60.0, 2.0)):
        assert recipe_estimate_every_s(tau, 0.1) == every, tau
    # the shipped policies trained with the recipes' default for their tau (30 s -> 1 s, 20 s -> 0.6 s),
    # recorded, and fly with it; the same spec without the setting (an older policy) takes 0.1 s
    for regime, every in (("horizontal", 1.0), ("vertical", 0.6)):
        spec = load_checkpoint(CHECKPOINT_DIR / f"policy_{regime}.pt", "policy")["env_spec"]
        assert policy_env_settings(spec, None)["estimate_every_s"] == every == recipe_estimate_every_s(spec["ema_tau_s"], 0.1)
        older = {key: value for key, value in spec.items() if key != "estimate_every_s"}
        assert policy_env_settings(older, None)["estimate_every_s"] == 0.1
