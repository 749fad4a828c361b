"""The wind estimator: causality, loss terms, metrics against hand-computed values, the --quick
training run (learns, resumes exactly, writes its artifacts), checkpoint reload and schema checks."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from quadwind_trl.estimator.features import HORIZONTAL_CHANNELS, VERTICAL_CHANNELS
from quadwind_trl.data.generate import generate_dataset, quick_spec
from quadwind_trl.evaluation.estimation import (
    FlightSequences,
    bin_index,
    bin_labels,
    FLIGHT_AGGREGATES,
    ema_sweep,
    evaluate_sequences,
    flight_aggregates,
    per_flight_aggregation,
    predict_flights,
    trailing_mean_floor,
    turbulence_floor,
)
from quadwind_trl.estimator.metrics import (
    ConstantReference,
    component_rmse,
    direction_errors_deg,
    estimation_metrics,
    least_squares_slope,
    pearson,
    per_flight_vector_rmse,
    vector_rmse,
)
from quadwind_trl.estimator.loss import EstimatorLoss, EstimatorLossConfig, wind_angle
from quadwind_trl.estimator import AttentionGRUEstimator, EstimatorBundle, EstimatorConfig
from quadwind_trl.estimator.training import (
    evaluate_table,
    load_estimator_data,
    lr_factor,
    quick_config,
    resume_path,
    train_estimator,
)

REPO = Path(__file__).resolve().parent.parent


def small_bundle(channels=VERTICAL_CHANNELS, seed=0) -> EstimatorBundle:
    torch.manual_seed(seed)
    c = len(channels)
    model = AttentionGRUEstimator(EstimatorConfig(in_channels=c, hidden=16, attention_dim=8, head_hidden=(16, 8))).eval()
    return EstimatorBundle(
        model=model, schema="vertical" if c == 22 else "horizontal", channels=tuple(channels),
        feature_mean=torch.randn(c), feature_std=torch.rand(c) + 0.5,
        label_mean=torch.tensor([1.0, -2.0]), label_std=torch.tensor([3.0, 4.0]),
    )  # fmt: skip


# ---------------------------------------------------------------------------------------------
# model: causality, reload, schema
# ---------------------------------------------------------------------------------------------


def test_estimate_depends_only_on_its_window_and_on_its_last_sample():
    bundle = small_bundle()
    c = len(VERTICAL_CHANNELS)
    feats = torch.randn(1, 200, c)
    labels, alt = torch.zeros(1, 200, 2), torch.zeros(1, 200)
    ids = torch.zeros(1, dtype=torch.long)

    def run(f):
        seq = predict_flights(bundle.predict, f, labels, alt, ids, torch.tensor([0]), torch.tensor([200]), ids, ids)
        return seq.pred[0]  # entry k: the window ending at sample 59 + k

    base = run(feats)
    end = 120
    k = end - 59
    outside = feats.clone()
    outside[:, : end - 59] = torch.randn(end - 59, c) * 10  # before the window
    outside[:, end + 1 :] = torch.randn(200 - end - 1, c) * 10  # after it (the future)
    assert torch.equal(run(outside)[k], base[k])
    last = feats.clone()
    last[:, end] += 1.0
    changed = run(last)
    assert not torch.allclose(changed[k], base[k])
    assert torch.equal(changed[k - 1], base[k - 1])  # earlier estimates never see a later sample
    # the window-mean wind is the mean over exactly the window's samples
    wind = torch.randn(1, 200, 2)
    seq = predict_flights(bundle.predict, feats, labels, alt, ids, torch.tensor([0]), torch.tensor([200]), ids, ids, wind=wind)
    torch.testing.assert_close(seq.wind_window[0, k], wind[0, end - 59 : end + 1].mean(0))
    torch.testing.assert_close(seq.wind[0, k], wind[0, end])
    # the same numbers as calling the model on the window directly
    direct = bundle.predict(feats[:, end - 59 : end + 1])
    torch.testing.assert_close(base[k], direct[0])


def test_saved_checkpoint_reloads_to_identical_outputs(tmp_path):
    bundle = small_bundle()
    bundle.manifest = {"metrics": {"per_window_vector_rmse": 1.0}}
    path = tmp_path / "est.pt"
    bundle.save(path)
    assert path.exists() and path.with_suffix(".json").exists()
    loaded = EstimatorBundle.load(path, expect_channels=VERTICAL_CHANNELS)
    x = torch.randn(7, 60, len(VERTICAL_CHANNELS))
    assert torch.equal(loaded.predict(x), bundle.predict(x))
    assert loaded.manifest == bundle.manifest and loaded.channels == bundle.channels
    assert not any(p.requires_grad for p in loaded.model.parameters()) and not loaded.model.training


def test_checkpoints_name_their_network_and_the_shipped_ones_default_to_the_attention_gru(tmp_path):
    """The loader builds the class a checkpoint names (a registry), not a hard-coded one; the
    shipped checkpoints name the attention-GRU, and checkpoints that predate the name load as it."""
    from dataclasses import dataclass

    from quadwind_trl.estimator import load_estimator, register_model
    from quadwind_trl.estimator.checkpoint import MODELS
    from quadwind_trl.manifest import CHECKPOINT_DIR
    from quadwind_trl.validation import load_checkpoint

    for regime in ("horizontal", "vertical"):
        assert load_checkpoint(CHECKPOINT_DIR / f"estimator_{regime}.pt", "estimator")["model"] == "attention_gru"
        assert type(load_estimator(regime).model) is AttentionGRUEstimator
    path = tmp_path / "gru.pt"
    small_bundle().save(path)
    payload = torch.load(path, weights_only=True)
    assert payload["model"] == "attention_gru"
    del payload["model"]  # as saved before checkpoints named their network
    torch.save(payload, tmp_path / "unnamed.pt")
    assert type(EstimatorBundle.load(tmp_path / "unnamed.pt").model) is AttentionGRUEstimator

    @dataclass(frozen=True)
    class MeanConfig:
        in_channels: int
        window: int = 60

    class WindowMean(torch.nn.Module):  # a second network: the window mean of two channels
        def __init__(self, cfg: MeanConfig):
            super().__init__()
            self.cfg = cfg
            self.gain = torch.nn.Parameter(torch.ones(2))

        def forward(self, x):
            return x[..., :2].mean(1) * self.gain

    register_model("window_mean", WindowMean, MeanConfig)
    try:
        b = small_bundle()
        b.model = WindowMean(MeanConfig(len(VERTICAL_CHANNELS), window=30))
        b.save(tmp_path / "mean.pt")
        loaded = EstimatorBundle.load(tmp_path / "mean.pt")
        assert type(loaded.model) is WindowMean and loaded.window == 30
        x = torch.randn(4, 30, len(VERTICAL_CHANNELS))
        assert torch.equal(loaded.predict(x), b.predict(x))
    finally:
        del MODELS["window_mean"]
    with pytest.raises(ValueError, match="model='window_mean'; registered"):
        EstimatorBundle.load(tmp_path / "mean.pt")


def test_loading_with_another_feature_schema_fails_clearly(tmp_path):
    path = tmp_path / "est.pt"
    small_bundle().save(path)
    with pytest.raises(ValueError, match=r"'vertical' feature schema \(22 channels\).*48 channels"):
        EstimatorBundle.load(path, expect_channels=HORIZONTAL_CHANNELS)


def test_parameter_count_is_within_two_percent_of_the_paper():
    n = sum(p.numel() for p in AttentionGRUEstimator(EstimatorConfig(in_channels=22)).parameters())
    assert abs(n - 133_315) / 133_315 < 0.02


# ---------------------------------------------------------------------------------------------
# loss
# ---------------------------------------------------------------------------------------------


def plain_loss(**kw) -> EstimatorLoss:
    """Standardisation mean 0, std 1: standardised and physical values coincide."""
    return EstimatorLoss(torch.zeros(2), torch.ones(2), EstimatorLossConfig(**kw))


def test_loss_is_zero_for_a_perfect_estimate_with_finite_gradients():
    y = torch.tensor([[3.0, 4.0], [0.0, 10.0], [0.0, 0.0]])
    pred = y.clone().requires_grad_(True)
    loss, terms = plain_loss()(pred, y)
    assert float(loss.detach()) == 0.0 and all(float(v) == 0.0 for v in terms.values())
    loss.backward()
    assert torch.isfinite(pred.grad).all()
    zero = torch.zeros(2, 2, requires_grad=True)  # an all-zero estimate: the angle is undefined
    plain_loss()(zero, torch.tensor([[3.0, 4.0], [1.0, 0.0]]))[0].backward()
    assert torch.isfinite(zero.grad).all()


def test_loss_terms_hand_computed():
    # same speed (5 m/s), rotated: Huber of (1, -1) = 0.5 each; angle acos(24/25); no speed error
    loss, t = plain_loss()(torch.tensor([[4.0, 3.0]]), torch.tensor([[3.0, 4.0]]))
    angle = math.acos(24 / 25)
    assert float(t["huber"]) == pytest.approx(0.5)
    assert float(t["speed"]) == pytest.approx(0.0, abs=1e-6)
    assert float(t["direction"]) == pytest.approx(angle, abs=1e-4)
    assert float(loss) == pytest.approx(0.5 + 0.05 * angle, abs=1e-5)
    # same direction, 2 m/s too fast: Huber(0, 2) = (0 + 1.5) / 2; speed Huber(2) = 1.5; angle 0
    loss, t = plain_loss()(torch.tensor([[0.0, 12.0]]), torch.tensor([[0.0, 10.0]]))
    assert float(t["huber"]) == pytest.approx(0.75)
    assert float(t["speed"]) == pytest.approx(1.5)
    assert float(t["direction"]) == pytest.approx(0.0, abs=1e-6)
    assert float(loss) == pytest.approx(0.75 + 0.03 * 1.5)


def test_auxiliary_terms_are_weighted_by_true_speed():
    # speed errors 1 m/s (true 2 m/s) and 0 (true 10 m/s): weighted mean (2 x 0.5 + 10 x 0) / 12
    pred = torch.tensor([[0.0, 3.0], [0.0, 10.0]])
    true = torch.tensor([[0.0, 2.0], [0.0, 10.0]])
    _, t = plain_loss()(pred, true)
    assert float(t["speed"]) == pytest.approx(1 / 12)
    _, t = plain_loss(speed_weighting="none")(pred, true)
    assert float(t["speed"]) == pytest.approx(0.25)
    # direction: 90 deg off at 1 m/s and exact at 9 m/s -> (1 x pi/2 + 9 x 0) / 10
    _, t = plain_loss()(torch.tensor([[1.0, 0.0], [9.0, 0.0]]), torch.tensor([[0.0, 1.0], [9.0, 0.0]]))
    assert float(t["direction"]) == pytest.approx(math.pi / 20, abs=1e-4)


def test_auxiliary_terms_are_in_physical_units():
    mean, std = torch.tensor([1.0, 2.0]), torch.tensor([2.0, 4.0])
    loss_fn = EstimatorLoss(mean, std)
    true = torch.tensor([[0.0, 10.0]])
    pred = torch.tensor([[0.0, 12.0]])  # 2 m/s too fast
    _, t = loss_fn((pred - mean) / std, (true - mean) / std)
    assert float(t["speed"]) == pytest.approx(1.5)
    assert float(t["huber"]) == pytest.approx(0.5 * 0.5 * 0.5**2)  # 0.5 std in east: 0.5 x 0.25, halved
    assert float(wind_angle(torch.tensor([1.0, 0.0]), torch.tensor([-1.0, 0.0]))) == pytest.approx(math.pi)


def test_lr_schedule_warms_up_then_decays():
    assert lr_factor(0, 10, 100, 0.0) == pytest.approx(0.1)
    assert lr_factor(9, 10, 100, 0.0) == pytest.approx(1.0)
    assert lr_factor(55, 10, 100, 0.0) == pytest.approx(0.5)
    assert lr_factor(100, 10, 100, 0.02) == pytest.approx(0.02)


# ---------------------------------------------------------------------------------------------
# metrics, each against a hand-computed example
# ---------------------------------------------------------------------------------------------

# four windows of two flights, (north, east) m/s
TRUE = torch.tensor([[0.0, 2.0], [2.0, 0.0], [2.0, 2.0], [0.0, 4.0]])
PRED = torch.tensor([[0.0, 3.0], [2.0, 1.0], [1.0, 1.0], [-1.0, 4.0]])
FLIGHT = torch.tensor([0, 0, 1, 1])


def test_vector_and_component_rmse():
    # errors (0,1) (0,1) (-1,-1) (-1,0): |e|^2 = 1, 1, 2, 1
    assert vector_rmse(PRED, TRUE) == pytest.approx(math.sqrt(5 / 4))
    n, e = component_rmse(PRED, TRUE)
    assert n == pytest.approx(math.sqrt(2 / 4)) and e == pytest.approx(math.sqrt(3 / 4))
    m = estimation_metrics(PRED, TRUE)
    assert m["component_mean_rmse"] == pytest.approx(0.5 * (math.sqrt(0.5) + math.sqrt(0.75)))


def test_per_flight_vector_rmse():
    # flight 0: mean estimate (1, 2), mean label (1, 1) -> error (0, 1)
    # flight 1: mean estimate (0, 2.5), mean label (1, 3) -> error (-1, -0.5), |e|^2 = 1.25
    assert per_flight_vector_rmse(PRED, TRUE, FLIGHT) == pytest.approx(math.sqrt((1 + 1.25) / 2))


def test_direction_mae():
    # angles: 0, atan(1/2), 0, atan(1/4)
    expect = [0.0, math.degrees(math.atan(0.5)), 0.0, math.degrees(math.atan(0.25))]
    torch.testing.assert_close(direction_errors_deg(PRED, TRUE), torch.tensor(expect, dtype=torch.float64), atol=1e-9, rtol=0)
    assert estimation_metrics(PRED, TRUE)["direction_mae_deg"] == pytest.approx(sum(expect) / 4)
    # across the +-180 deg cut: 170 vs -170 deg is 20 deg
    a = torch.tensor([[math.sin(math.radians(170)), math.cos(math.radians(170))]])
    b = torch.tensor([[math.sin(math.radians(-170)), math.cos(math.radians(-170))]])
    assert float(direction_errors_deg(a, b)[0]) == pytest.approx(20.0, abs=1e-4)


def test_pearson():
    # a = (1,2,3), b = (2,4,7): cov sum 5, var sums 2 and 114/9
    assert pearson(torch.tensor([1.0, 2.0, 3.0]), torch.tensor([2.0, 4.0, 7.0])) == pytest.approx(5 / math.sqrt(2 * 114 / 9))
    m = estimation_metrics(PRED, TRUE)
    assert m["corr_n"] == pytest.approx(pearson(PRED[:, 0], TRUE[:, 0]))


def test_skill_scores_against_the_best_constant():
    m = estimation_metrics(PRED, TRUE)
    # best constant vector: the mean label (1, 2); its errors (-1,0) (1,-2) (1,0) (-1,2): mean |e|^2 = 3
    assert m["reference_vector_rmse"] == pytest.approx(math.sqrt(3))
    assert m["vector_skill"] == pytest.approx(1 - math.sqrt(1.25) / math.sqrt(3))
    # speeds: true 2, 2, 2 sqrt2, 4; estimated 3, sqrt5, sqrt2, sqrt17
    st = [2.0, 2.0, 2 * math.sqrt(2), 4.0]
    sp = [3.0, math.sqrt(5), math.sqrt(2), math.sqrt(17)]
    speed_rmse = math.sqrt(sum((a - b) ** 2 for a, b in zip(sp, st)) / 4)
    mean_speed = sum(st) / 4
    ref = math.sqrt(sum((b - mean_speed) ** 2 for b in st) / 4)
    assert m["speed_rmse"] == pytest.approx(speed_rmse)
    assert m["reference_speed_rmse"] == pytest.approx(ref)
    assert m["speed_skill"] == pytest.approx(1 - speed_rmse / ref)
    # with another set's reference (breakdowns keep the whole set's constants)
    r = ConstantReference((0.0, 0.0), 0.0)
    m0 = estimation_metrics(PRED, TRUE, reference=r)
    assert m0["reference_vector_rmse"] == pytest.approx(math.sqrt((4 + 4 + 8 + 16) / 4))


def test_altitude_speed_slope():
    assert least_squares_slope(torch.tensor([0.0, 100.0, 200.0]), torch.tensor([1.0, 2.0, 3.5])) == pytest.approx(250 / 20000)
    m = estimation_metrics(PRED, TRUE, altitude=torch.tensor([0.0, 100.0, 200.0, 300.0]))
    # true speeds 2, 2, 2.828, 4 at 0..300 m: slope = sum(dx dy) / sum(dx^2), dx = -150,-50,50,150
    st = torch.tensor([2.0, 2.0, 2 * math.sqrt(2), 4.0], dtype=torch.float64)
    dx = torch.tensor([-150.0, -50.0, 50.0, 150.0], dtype=torch.float64)
    assert m["altitude_speed_slope_true"] == pytest.approx(float((dx * (st - st.mean())).sum() / (dx * dx).sum()))


def test_bins_and_breakdowns():
    edges = (0.0, 4.0, 8.0, 12.0, 16.0, math.inf)
    assert bin_labels(edges) == ["0-4", "4-8", "8-12", "12-16", ">16"]
    assert bin_index(torch.tensor([0.0, 3.99, 4.0, 15.9, 16.0, 40.0]), edges).tolist() == [0, 0, 1, 3, 4, 4]
    # two flights of two trajectories, left-aligned sequences of length 2
    seq = FlightSequences(
        flights=torch.tensor([0, 1]), pred=PRED.reshape(2, 2, 2), true=TRUE.reshape(2, 2, 2),
        altitude=torch.tensor([[100.0, 100.0], [500.0, 500.0]]), wind=TRUE.reshape(2, 2, 2),
        end=torch.tensor([[59, 60], [59, 60]]), mask=torch.ones(2, 2, dtype=torch.bool),
        traj_id=torch.tensor([0, 1]), case_id=torch.tensor([0, 1]), dt_s=0.1,
    )  # fmt: skip
    names = ["a", "b"]
    r = evaluate_sequences(seq, names)
    assert r["summary"]["per_window_vector_rmse"] == pytest.approx(math.sqrt(1.25))
    assert r["summary"]["per_flight_vector_rmse"] == pytest.approx(math.sqrt(1.125))
    assert set(r["by_trajectory"]) == {"a", "b"}
    assert r["by_trajectory"]["a"]["per_window_vector_rmse"] == pytest.approx(1.0)  # errors (0,1), (0,1)
    assert r["by_trajectory"]["b"]["per_window_vector_rmse"] == pytest.approx(math.sqrt(1.5))
    assert set(r["by_altitude"]) == {"0-150", ">450"}
    assert r["by_speed"]["0-4"]["n_windows"] == 3 and r["by_speed"]["4-8"]["n_windows"] == 1
    # skill in a breakdown keeps the whole set's reference
    assert r["by_trajectory"]["a"]["reference_vector_rmse"] == pytest.approx(math.sqrt((1 + 5) / 2))
    sweep = ema_sweep(seq, (0.0, 3.0))
    assert sweep[0.0]["per_window_vector_rmse"] == pytest.approx(math.sqrt(1.25))
    # turbulence floor: total wind = label + (1, 0) at each window end, + (0, 2) over the window
    assert r["turbulence_floor"]["turbulence_rmse_instantaneous"] == pytest.approx(0.0)  # wind := TRUE above
    seq.wind = seq.true + torch.tensor([1.0, 0.0])
    seq.wind_window = seq.true + torch.tensor([0.0, 2.0])
    floor = turbulence_floor(seq)
    assert floor["turbulence_rmse_instantaneous"] == pytest.approx(1.0)
    assert floor["turbulence_rmse_window_mean"] == pytest.approx(2.0)
    assert floor["turbulence_rmse_flight_mean"] == pytest.approx(1.0)
    assert turbulence_floor(seq, torch.tensor([True, True, False, False]))["turbulence_rmse_flight_mean"] == pytest.approx(1.0)


# ---------------------------------------------------------------------------------------------
# training: --quick end to end on a tiny generated dataset
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def quick_vertical(tmp_path_factory):
    """A generated --quick vertical dataset: 10 wind cases (7/2/1 by case), 20 m flights."""
    spec, _ = quick_spec("vertical", seed=0, cases=10)
    path = tmp_path_factory.mktemp("est") / "flights_vertical_quick"
    generate_dataset(path, spec, progress=False)
    return path


def test_quick_training_lowers_validation_loss_and_writes_artifacts(quick_vertical, tmp_path):
    ed = load_estimator_data(quick_vertical, "vertical", quick=True, progress=False)
    cfg = quick_config("vertical", epochs=8, windows_per_epoch=512)
    out = tmp_path / "est.pt"
    result = train_estimator(ed, cfg, out, log_dir=tmp_path / "logs", progress=False)
    val_losses = [h["val_loss"] for h in result.history]
    assert min(val_losses) < 0.9 * result.initial_val["loss"], (result.initial_val["loss"], val_losses)
    assert result.history[-1]["train_loss"] < result.history[0]["train_loss"]
    # the best bundle with its manifest; metrics under self-explaining keys
    manifest = json.loads(out.with_suffix(".json").read_text())
    for key in ("per_flight_vector_rmse", "per_window_vector_rmse", "component_mean_rmse", "direction_mae_deg",
                "corr_n", "corr_e", "vector_skill", "speed_skill", "wall_time_s"):  # fmt: skip
        assert key in manifest["metrics"], key
    assert manifest["dataset"]["manifest_sha256"] == ed.info["manifest_sha256"]
    assert manifest["config"]["regime"] == "vertical" and "git_commit" in manifest and manifest["command"] is None
    bundle = EstimatorBundle.load(out, expect_channels=VERTICAL_CHANNELS)
    assert bundle.schema == "vertical"
    # the bundle reproduces the best epoch's validation metrics on raw features
    table = ed.windows.tables["val"]
    val = evaluate_table(bundle.model, ed.windows, table)
    assert val["per_window_vector_rmse"] == pytest.approx(result.best_val["per_window_vector_rmse"], rel=1e-5)
    # TorchRL CSV logs
    scalars = tmp_path / "logs" / result.exp_name / "scalars"
    assert (scalars / "val" / "per_window_vector_rmse.csv").exists() and (scalars / "train" / "loss.csv").exists()
    assert (tmp_path / "logs" / result.exp_name / "best.pt").exists()
    # an existing checkpoint is never silently replaced
    with pytest.raises(FileExistsError):
        train_estimator(ed, cfg, out, log_dir=tmp_path / "logs", progress=False)


def test_a_share_of_the_training_cases_leaves_validation_and_test_alone(quick_vertical):
    full = load_estimator_data(quick_vertical, "vertical", quick=True, progress=False)
    half = load_estimator_data(quick_vertical, "vertical", quick=True, progress=False, train_fraction=0.5)
    train, kept = full.windows.split_cases["train"], half.windows.split_cases["train"]
    assert kept.numel() == round(0.5 * train.numel()) and torch.isin(kept, train).all()
    for split in ("val", "test"):
        assert torch.equal(half.windows.split_cases[split], full.windows.split_cases[split])
        assert torch.equal(half.windows.tables[split], full.windows.tables[split])
    assert half.info["train_fraction"] == 0.5
    with pytest.raises(ValueError, match=r"train_fraction=0.0; allowed: \(0, 1\]"):
        load_estimator_data(quick_vertical, "vertical", quick=True, progress=False, train_fraction=0.0)


def test_interrupted_run_resumes_to_the_same_result(quick_vertical, tmp_path):
    ed = load_estimator_data(quick_vertical, "vertical", quick=True, progress=False)
    cfg = quick_config("vertical", epochs=3, windows_per_epoch=128)
    full = train_estimator(ed, cfg, tmp_path / "a.pt", log_dir=tmp_path / "logs", progress=False)
    part = train_estimator(ed, cfg, tmp_path / "b.pt", log_dir=tmp_path / "logs", progress=False, stop_after_epochs=1)
    assert part.bundle is None and len(part.history) == 1
    assert not (tmp_path / "b.pt").exists()  # the checkpoint appears only when training ends
    assert not torch.load(resume_path(tmp_path / "b.pt", tmp_path / "logs"), weights_only=False)["finished"]
    with pytest.raises(ValueError, match="configuration differs"):
        train_estimator(ed, replace(cfg, lr=1e-3), tmp_path / "b.pt", resume=True, log_dir=tmp_path / "logs", progress=False)
    resumed = train_estimator(ed, cfg, tmp_path / "b.pt", resume=True, log_dir=tmp_path / "logs", progress=False)
    assert resumed.exp_name == part.exp_name
    assert [h["val_loss"] for h in resumed.history] == [h["val_loss"] for h in full.history]
    a = torch.load(resume_path(tmp_path / "a.pt", tmp_path / "logs"), weights_only=False)["model"]
    b = torch.load(resume_path(tmp_path / "b.pt", tmp_path / "logs"), weights_only=False)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    # --resume with nothing to resume starts the run (a pipeline can always pass it)
    fresh = train_estimator(ed, cfg, tmp_path / "c.pt", resume=True, log_dir=tmp_path / "logs", progress=False)
    assert [h["val_loss"] for h in fresh.history] == [h["val_loss"] for h in full.history]


def test_train_recipe_quick_runs_end_to_end(quick_vertical, tmp_path):
    out = tmp_path / "cli.pt"
    cmd = [sys.executable, str(REPO / "recipes" / "train_estimator.py"), "--regime", "vertical", "--data", str(quick_vertical),
           "--quick", "--epochs", "1", "--windows-per-epoch", "128", "--threads", "1", "--out", str(out),
           "--log-dir", str(tmp_path / "logs"), "--no-progress"]  # fmt: skip
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=REPO)
    assert r.returncode == 0, r.stderr[-2000:]
    manifest = json.loads(out.with_suffix(".json").read_text())
    assert "train_estimator.py" in manifest["command"] and manifest["epochs_run"] == 1
    # the wrong regime for the dataset fails with a message naming it (the recipe reports it)
    with pytest.raises(ValueError, match="'vertical' dataset, not 'horizontal'"):
        load_estimator_data(quick_vertical, "horizontal", progress=False)


def test_flight_aggregates_by_hand():
    """Two flights, the second with 3 real windows and 2 of padding: each rule by hand."""
    north = torch.tensor([[1.0, 9.0, 2.0, 4.0, 3.0], [5.0, 1.0, 3.0, 7.0, 7.0]])
    pred = torch.stack((north, -north), -1)
    mask = torch.tensor([[True] * 5, [True, True, True, False, False]])
    true = torch.zeros(2, 5, 2)
    true[1, :, 0] = 1.0  # flight 1's label (1, 0); the padding's values must not count
    true[1, 3:, 0] = 50.0
    seq = FlightSequences(
        flights=torch.tensor([0, 1]), pred=pred, true=true, altitude=torch.zeros(2, 5), wind=true,
        end=torch.arange(5).expand(2, 5), mask=mask, traj_id=torch.tensor([0, 1]), case_id=torch.tensor([0, 1]), dt_s=0.1,
    )  # fmt: skip
    agg = flight_aggregates(seq)
    expect_north = {  # flight 0: 1 9 2 4 3 (sorted 1 2 3 4 9); flight 1: 5 1 3
        "mean": (19 / 5, 3.0), "median": (3.0, 3.0), "trimmed_mean_20": (3.0, 3.0),  # 20 % of 5 = 1 off each end; of 3 = 0
        "second_half_mean": ((2 + 4 + 3) / 3, (1 + 3) / 2), "last": (3.0, 3.0),
    }
    for name, (a, b) in expect_north.items():
        torch.testing.assert_close(agg[name], torch.tensor([[a, -a], [b, -b]], dtype=torch.float64), msg=name)
    assert agg["label"].tolist() == [[0.0, 0.0], [1.0, 0.0]]
    rmse = per_flight_aggregation(seq)
    assert set(rmse) == set(FLIGHT_AGGREGATES)
    assert rmse["mean"] == pytest.approx(evaluate_sequences(seq, ["a", "b"])["summary"]["per_flight_vector_rmse"])
    assert rmse["last"] == pytest.approx(math.sqrt((18 + (2 * 2 + 3 * 3)) / 2))


def test_trailing_mean_floor_by_hand():
    """Wind 0, 1, 2, ... (north) over a constant label 0: the trailing mean of the last w samples
    ending at e is e - (w - 1) / 2, expanding (e / 2) before the flight has w samples."""
    t_len = 20
    wind = torch.zeros(2, t_len, 2)
    wind[1, :, 0] = torch.arange(t_len, dtype=torch.float32)
    labels = torch.zeros(2, t_len, 2)
    table = torch.tensor([[1, 3], [1, 15], [0, 15]])
    floor = trailing_mean_floor(wind, labels, table, [1, 4, 10])
    for w, (a, b) in {1: (3.0, 15.0), 4: (1.5, 13.5), 10: (1.5, 10.5)}.items():
        assert floor[w] == pytest.approx(math.sqrt((a * a + b * b) / 3)), w
    # from flight 1's sample 2 on: the mean of 2..3 is 2.5 and, with w = 10, of 6..15 still 10.5
    since = trailing_mean_floor(wind, labels, table, [10, 100], first=torch.tensor([0, 2]))
    assert since[10] == pytest.approx(math.sqrt((2.5**2 + 10.5**2) / 3))
    assert since[100] == pytest.approx(math.sqrt((2.5**2 + 8.5**2) / 3))
