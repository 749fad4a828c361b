"""Training of the attention-GRU wind estimator (paper, Sections "Architecture", "Training
configuration" of both regimes).

Adam (3e-4, weight decay 1e-5), linear warm-up then cosine decay per optimiser step, batch 256,
Gaussian input noise on the standardised features, the wind-case-balanced sampler, the loss of
:mod:`quadwind_trl.estimator.loss`. Model selection and early stopping on the validation
per-window vector RMSE (m/s), evaluated every epoch.

Artifacts of a run writing to ``out`` (e.g. ``quadwind_trl/checkpoints/estimator_horizontal.pt``):

* ``out`` and its manifest ``out`` with suffix ``.json``: the best checkpoint as an
  :class:`EstimatorBundle` (weights, schema, channel names, feature and label standardisation)
  and its manifest (command, configuration, git commit, dataset manifest hash,
  validation and test metrics). Written atomically once, when training ends; until then the best
  model so far lives in ``log_dir/<exp_name>/best.pt`` (+ ``.json``), so an interrupted run never
  leaves a half-trained model at ``out``.
* ``resume_path(out, log_dir)``: the full training state after the last completed epoch (model,
  optimiser, scheduler, early-stopping counters, history, logger name), written atomically every
  epoch. ``resume=True`` continues from it; every epoch reseeds the RNG from ``(seed, epoch)``, so
  an interrupted and resumed run ends with the same weights as an uninterrupted one.
* TorchRL ``CSVLogger`` scalars under ``log_dir/<exp_name>/scalars/*.csv`` (``exp_name`` unique
  per run, reused on resume so the curves continue from the resume state's epoch: the rows an
  interrupted run logged after it are dropped first).

The run holds :class:`~quadwind_trl.outputs.OutputLock` on ``out`` throughout: a second run
writing the same checkpoint (a resume included) is refused at once.

Budget (measured, see ``docs/estimator.md``): the defaults in :func:`full_config` bound the
horizontal run at 25 epochs x 80k windows drawn by the balanced sampler.
"""
from __future__ import annotations

import copy
import hashlib
import math
import os
import time
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Callable

import torch
from torch import Tensor

from ..data.generate import load_dataset
from ..data.windows import SPLIT_FRACTIONS, WINDOW, WindowedData, compute_features, prepare_windows, window_table
from ..manifest import CheckpointParts, git_commit, platform_info, repo_relative, save_atomic
from ..outputs import OutputLock, truncate_scalar_logs
from .base import WindEstimator
from .checkpoint import EstimatorBundle
from .features import DEFAULT_TRAILING_WINDOWS, FeatureExtractor, make_extractor
from .loss import EstimatorLoss, EstimatorLossConfig
from .metrics import estimation_metrics
from .model import AttentionGRUEstimator, EstimatorConfig

REGIMES = ("horizontal", "vertical")
QUICK_FRACTIONS = (1 / 3, 1 / 3, 1 / 3)  # --quick on a 3-case dataset: one case per split


@dataclass(frozen=True)
class TrainConfig:
    regime: str = "horizontal"
    epochs: int = 25  # paper: horizontal 25; vertical up to 150
    windows_per_epoch: int | None = 80_000  # draws of the balanced sampler; None = the split's window count
    batch_size: int = 256  # paper
    lr: float = 3e-4  # paper
    weight_decay: float = 1e-5  # paper
    warmup_epochs: float = 1.0  # ours: linear warm-up length
    min_lr_ratio: float = 0.02  # ours: the cosine decays to this fraction of lr
    input_noise_std: float = 0.05  # ours: "light" Gaussian noise, in standardised feature units
    feature_dropout: float = 0.0  # paper: 0.1 for the vertical model
    head_dropout: float = 0.2  # paper
    patience: int | None = None  # paper: 25 for the vertical model (epochs without improvement)
    grad_clip_norm: float | None = 1.0  # ours
    val_stride: int | None = 48  # validation windows every 4.8 s (None: the training stride)
    test_stride: int | None = None  # final test metrics in the manifest (None: the training stride)
    eval_batch_size: int = 1024  # measured: batch 4096 is 2-3x slower per window than 256-1024 (cache)
    seed: int = 0
    compile: bool = False
    log_every_steps: int = 50
    loss: EstimatorLossConfig = field(default_factory=EstimatorLossConfig)
    # the inputs and the network, settable for experiments (the defaults are the paper's)
    window: int = WINDOW  # samples the network reads per estimate (60 = 6 s at 10 Hz)
    trailing_windows: tuple[int, ...] | None = None  # trailing-mean lengths, samples (None: the regime's, DEFAULT_TRAILING_WINDOWS)
    hidden: int = 128  # GRU state and attention width
    gru_layers: int = 1
    head_hidden: tuple[int, int] = (128, 64)
    train_fraction: float = 1.0  # share of the training cases used (validation and test unchanged)

    def __post_init__(self):
        if self.regime not in REGIMES:
            raise ValueError(f"TrainConfig.regime={self.regime!r}; allowed: {REGIMES}")
        for name in ("epochs", "batch_size", "eval_batch_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"TrainConfig.{name}={getattr(self, name)} must be >= 1")
        if self.windows_per_epoch is not None and self.windows_per_epoch < 1:
            raise ValueError(f"TrainConfig.windows_per_epoch={self.windows_per_epoch} must be >= 1 or None")
        if not 0.0 <= self.feature_dropout < 1.0 or not 0.0 <= self.head_dropout < 1.0:
            raise ValueError("TrainConfig.feature_dropout and head_dropout must lie in [0, 1)")
        if self.lr <= 0 or self.input_noise_std < 0 or not 0 <= self.min_lr_ratio <= 1:
            raise ValueError("TrainConfig: lr must be > 0, input_noise_std >= 0, min_lr_ratio in [0, 1]")
        for name, low in (("window", 2), ("hidden", 1), ("gru_layers", 1)):
            if getattr(self, name) < low:
                raise ValueError(f"TrainConfig.{name}={getattr(self, name)} must be >= {low}")
        if len(self.head_hidden) != 2 or min(self.head_hidden) < 1:
            raise ValueError(f"TrainConfig.head_hidden={self.head_hidden!r}: two layer widths >= 1 allowed")
        if not 0.0 < self.train_fraction <= 1.0:
            raise ValueError(f"TrainConfig.train_fraction={self.train_fraction!r}; allowed: (0, 1]")
        if self.trailing_windows is None:  # resolved here, so a manifest records what the run used
            object.__setattr__(self, "trailing_windows", DEFAULT_TRAILING_WINDOWS[self.regime])

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        d = dict(d)
        d["loss"] = EstimatorLossConfig(**d.get("loss", {}))
        for name in ("trailing_windows", "head_hidden"):  # JSON round trips make tuples lists
            if name in d:
                d[name] = tuple(d[name])
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in known})


def full_config(regime: str, **overrides) -> TrainConfig:
    """The full-scale recipe of ``regime`` (see ``docs/estimator.md`` for the budget)."""
    if regime == "horizontal":
        cfg = TrainConfig(regime="horizontal", epochs=25, windows_per_epoch=80_000)
    elif regime == "vertical":
        cfg = TrainConfig(  # validation every 9.6 s: it runs up to 150 times
            regime="vertical", epochs=150, windows_per_epoch=40_000, patience=25, feature_dropout=0.1, val_stride=96
        )
    else:
        raise ValueError(f"regime={regime!r}; allowed: {REGIMES}")
    return replace(cfg, **overrides)


def quick_config(regime: str, **overrides) -> TrainConfig:
    """A small run for smoke tests: a few short epochs at batch 64, dense validation (4 epochs:
    the toy pipeline shows that training runs, not what it reaches)."""
    base = full_config(regime)
    cfg = replace(
        base, epochs=4, windows_per_epoch=1024, batch_size=64, warmup_epochs=0.5, val_stride=None, patience=None
    )
    return replace(cfg, **overrides)


# ---------------------------------------------------------------------------------------------
# data
# ---------------------------------------------------------------------------------------------


def file_sha256(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@dataclass
class EstimatorData:
    """A dataset ready for the estimator: windows, splits, statistics and its provenance."""

    windows: WindowedData
    data: Any  # the memory-mapped TensorDict of load_dataset
    manifest: dict
    info: dict  # path, manifest hash, regime, cases, seed, split sizes

    @property
    def regime(self) -> str:
        return self.manifest["regime"]


def features_file(path: Path, fx: FeatureExtractor) -> Path:
    """The feature cache of ``fx`` in dataset ``path``: ``features_<regime>.memmap`` for the
    default extractor, the trailing windows in the name for others."""
    if fx.windows == DEFAULT_TRAILING_WINDOWS[fx.schema]:
        return path / f"features_{fx.schema}.memmap"
    return path / f"features_{fx.schema}_avg{'-'.join(map(str, fx.windows)) or 'none'}.memmap"


def load_estimator_data(
    path: str | os.PathLike,
    regime: str,
    *,
    quick: bool = False,
    progress: bool = True,
    fractions=SPLIT_FRACTIONS,
    window: int = WINDOW,
    trailing_windows: tuple[int, ...] | None = None,
    train_fraction: float = 1.0,
) -> EstimatorData:
    """Load a generated dataset, compute (or load the cached) features of ``regime``'s schema
    into ``path`` (:func:`features_file`) and prepare the windows of ``window`` samples.

    With ``quick`` and a dataset too small for the 70/15/15 split to give every split a case
    (fewer than about 7 cases), the cases are split in thirds instead."""
    path = Path(path)
    data, manifest = load_dataset(path)
    if manifest["regime"] != regime:
        raise ValueError(f"{path} is a {manifest['regime']!r} dataset, not {regime!r} (--regime)")
    fx = make_extractor(regime, windows=None if trailing_windows is None else tuple(trailing_windows))
    feats = compute_features(data["record"], fx, out=features_file(path, fx), progress=progress)
    shape = {"window": window, "train_fraction": train_fraction}
    wd = prepare_windows(data, manifest, feats, fx.channels, fractions=fractions, **shape)
    if quick and any(wd.tables[s].shape[0] == 0 for s in ("train", "val", "test")):
        fractions = QUICK_FRACTIONS
        wd = prepare_windows(data, manifest, feats, fx.channels, fractions=fractions, **shape)
    for split in ("train", "val"):
        if wd.tables[split].shape[0] == 0:
            raise ValueError(
                f"{path}: the {split!r} split has no windows ({len(wd.split_cases[split])} cases); "
                "generate more wind cases (--cases)"
            )
    info = {
        "path": repo_relative(path),
        "manifest_sha256": file_sha256(path / "manifest.json"),
        "regime": manifest["regime"],
        "cases": manifest["cases"],
        "seed": manifest["seed"],
        "num_flights": manifest["num_flights"],
        "turbulence_layout": manifest["config"]["turbulence"]["layout"],  # which field the flights flew through
        "split_fractions": list(fractions),
        "train_fraction": train_fraction,
        "window": window,
        "trailing_windows": list(fx.windows),
        "split_cases": {k: int(v.numel()) for k, v in wd.split_cases.items()},
        "split_windows": {k: int(v.shape[0]) for k, v in wd.tables.items()},
        "stride": wd.stride,
    }
    return EstimatorData(windows=wd, data=data, manifest=manifest, info=info)


def estimator_inputs(estimator: WindEstimator) -> dict:
    """The ``load_estimator_data`` arguments that give ``estimator`` the inputs it was trained on:
    its window length and the trailing means its channel names say."""
    fx = make_extractor(estimator.schema, channels=tuple(estimator.channels))  # refuses channels no extractor makes
    return {"window": int(estimator.window), "trailing_windows": fx.windows}


def split_flights(wd: WindowedData, split: str) -> Tensor:
    """Dataset rows of the flights of ``split`` that have windows."""
    return torch.unique(wd.tables[split][:, 0])


def strided_table(wd: WindowedData, split: str, stride: int | None) -> Tensor:
    """``[W, 2]`` windows of ``split``'s flights at ``stride`` (None: the training table)."""
    if stride is None or stride == wd.stride:
        return wd.tables[split]
    flights = split_flights(wd, split)
    return window_table(flights, wd.crop[flights], wd.length[flights], wd.window, stride)


# ---------------------------------------------------------------------------------------------
# schedule, evaluation
# ---------------------------------------------------------------------------------------------


def lr_factor(step: int, warmup_steps: int, total_steps: int, min_ratio: float) -> float:
    """Linear warm-up from ``1/warmup_steps`` to 1, then cosine decay to ``min_ratio``."""
    if warmup_steps > 0 and step < warmup_steps:
        return (step + 1) / warmup_steps
    span = max(total_steps - warmup_steps, 1)
    progress = min(max(step - warmup_steps, 0) / span, 1.0)
    return min_ratio + (1.0 - min_ratio) * 0.5 * (1.0 + math.cos(math.pi * progress))


@torch.no_grad()
def predict_table(
    model: torch.nn.Module, wd: WindowedData, table: Tensor, batch_size: int = 4096
) -> tuple[Tensor, Tensor]:
    """Standardised predictions and standardised labels ``[W, 2]`` of the windows of ``table``."""
    ds = wd.dataset("train")  # the table is swapped below; standardisation is the training one
    ds.table = table
    preds, labels = [], []
    was_training = model.training
    model.eval()
    for i in range(0, table.shape[0], batch_size):
        x, y = ds.batch(torch.arange(i, min(i + batch_size, table.shape[0])))
        preds.append(model(x))
        labels.append(wd.label_stats(y))
    model.train(was_training)
    if not preds:
        return torch.zeros(0, 2), torch.zeros(0, 2)
    return torch.cat(preds), torch.cat(labels)


def evaluate_table(
    model: torch.nn.Module,
    wd: WindowedData,
    table: Tensor,
    loss_fn: EstimatorLoss | None = None,
    batch_size: int = 4096,
) -> dict[str, float]:
    """Loss (if ``loss_fn``) and :func:`estimation_metrics` (m/s) over the windows of ``table``."""
    pred_std, y_std = predict_table(model, wd, table, batch_size)
    if pred_std.shape[0] == 0:
        return {"n_windows": 0}
    pred, true = wd.label_stats.inverse(pred_std), wd.label_stats.inverse(y_std)
    out = estimation_metrics(pred, true, flight=table[:, 0])
    if loss_fn is not None:
        with torch.no_grad():
            loss, terms = loss_fn(pred_std, y_std)
        out["loss"] = float(loss)
        out.update({f"loss_{k}": float(v) for k, v in terms.items()})
    return out


def headline(metrics: dict[str, float]) -> dict[str, float]:
    """The manifest's metric keys (self-explaining names)."""
    keys = (
        "per_flight_vector_rmse", "per_window_vector_rmse", "component_mean_rmse", "component_rmse_n",
        "component_rmse_e", "direction_mae_deg", "corr_n", "corr_e", "vector_skill", "speed_skill",
        "reference_vector_rmse", "speed_rmse", "n_windows", "n_flights", "loss",
    )  # fmt: skip
    return {k: metrics[k] for k in keys if k in metrics}


# ---------------------------------------------------------------------------------------------
# the run
# ---------------------------------------------------------------------------------------------


def resume_path(out: str | os.PathLike, log_dir: str | os.PathLike = "runs/estimator") -> Path:
    """The resume state of the run writing ``out``: in ``log_dir`` (never beside the shipped
    checkpoint), named after ``out``'s stem and a hash of its absolute path."""
    out = Path(out).resolve()
    return Path(log_dir) / f"resume-{out.stem}-{hashlib.sha1(str(out).encode()).hexdigest()[:8]}.pt"


def _logged_through(state: dict, steps_per_epoch: int) -> Callable[[str], float]:
    """The last step of each CSV log that a resume ``state`` covers: the per-epoch rows through its
    epoch, the per-optimiser-step loss through that epoch's last step, and no test rows (the
    run's end writes them again)."""
    epoch = state["epoch"]

    def last(name: str) -> float:
        if name.startswith("test/"):
            return float("-inf")
        return (epoch + 1) * steps_per_epoch if name == "train/step_loss" else epoch

    return last


@dataclass
class EstimatorTrainResult:
    """What :func:`train_estimator` returns (``bundle`` is None when stopped early by
    ``stop_after_epochs``)."""

    bundle: EstimatorBundle | None
    history: list[dict]
    best_epoch: int
    best_val: dict
    test: dict
    wall_time_s: float
    out: Path
    exp_name: str
    initial_val: dict | None = None  # validation metrics of the untrained model


def _make_bundle(model: AttentionGRUEstimator, wd: WindowedData, schema: str, manifest: dict) -> EstimatorBundle:
    return EstimatorBundle(
        model=copy.deepcopy(model),  # the bundle freezes its copy
        schema=schema,
        channels=tuple(wd.channels),
        feature_mean=wd.feature_stats.mean.clone(),
        feature_std=wd.feature_stats.std.clone(),
        label_mean=wd.label_stats.mean.clone(),
        label_std=wd.label_stats.std.clone(),
        manifest=manifest,
    )


def _resume_state(ed: EstimatorData, cfg: TrainConfig, out: Path, state_path: Path, resume: bool, overwrite: bool) -> dict | None:
    """The interrupted run's state to continue (``resume`` and a state exists), else None after
    checking that nothing would be overwritten by accident. ``resume`` without a state starts a new
    run, as the PPO recipes do, so a pipeline can always pass it (``recipes/reproduce.py``)."""
    if resume and state_path.exists():
        state = torch.load(state_path, map_location="cpu", weights_only=False)
        saved = TrainConfig.from_dict(state["config"])
        if saved != cfg:
            diff = {k: (v, getattr(cfg, k)) for k, v in saved.to_dict().items() if v != cfg.to_dict()[k]}
            raise ValueError(f"--resume: the configuration differs from the interrupted run's: {diff}")
        if state["dataset"]["manifest_sha256"] != ed.info["manifest_sha256"]:
            raise ValueError("--resume: the dataset differs from the interrupted run's (manifest hash)")
        return state
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} exists: pass overwrite=True (--overwrite) to replace it")
    if state_path.exists() and not overwrite:
        raise FileExistsError(f"an interrupted run writing {out} left {state_path}: pass resume=True (--resume) or overwrite=True (--overwrite)")
    if state_path.exists():  # overwrite: the stale state must not be resumed later
        state_path.unlink()
    return None


@dataclass
class _Progress:
    """What the run has achieved so far (saved every epoch in the resume state)."""

    history: list[dict] = field(default_factory=list)
    best: dict = field(default_factory=lambda: {"per_window_vector_rmse": math.inf})
    best_epoch: int = -1
    bad_epochs: int = 0
    start_epoch: int = 0
    wall_before: float = 0.0
    initial_val: dict | None = None  # validation metrics of the untrained model

    def update(self, val: dict, epoch: int) -> bool:
        """Record epoch ``epoch``'s validation metrics; True if they are the best so far."""
        improved = val["per_window_vector_rmse"] < self.best["per_window_vector_rmse"]
        if improved:
            self.best, self.best_epoch, self.bad_epochs = val, epoch, 0
        else:
            self.bad_epochs += 1
        return improved


class _Trainer(CheckpointParts):
    """The model, loss, optimiser, schedule and sampler of one run, and its per-epoch step."""

    checkpoint_parts = {"model": "model", "optimizer": "opt", "scheduler": "sched"}

    def __init__(self, wd: WindowedData, cfg: TrainConfig):
        self.wd, self.cfg = wd, cfg
        torch.manual_seed(cfg.seed)
        self.mcfg = EstimatorConfig(
            in_channels=len(wd.channels), hidden=cfg.hidden, attention_dim=cfg.hidden, head_hidden=cfg.head_hidden,
            gru_layers=cfg.gru_layers, dropout=cfg.head_dropout, feature_dropout=cfg.feature_dropout, window=wd.window,
        )  # fmt: skip
        self.model = AttentionGRUEstimator(self.mcfg)
        self.loss_fn = EstimatorLoss(wd.label_stats.mean, wd.label_stats.std, cfg.loss)
        self.opt = torch.optim.Adam(self.model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        self.per_epoch = cfg.windows_per_epoch or wd.tables["train"].shape[0]
        self.steps_per_epoch = math.ceil(self.per_epoch / cfg.batch_size)
        total_steps = self.steps_per_epoch * cfg.epochs
        warmup = int(round(cfg.warmup_epochs * self.steps_per_epoch))
        self.sched = torch.optim.lr_scheduler.LambdaLR(self.opt, lambda s: lr_factor(s, warmup, total_steps, cfg.min_lr_ratio))
        self.sampler = wd.sampler("train", seed=cfg.seed, num_samples=self.per_epoch)
        self.train_ds = wd.dataset("train")
        self.val_table = strided_table(wd, "val", cfg.val_stride)
        self.n_params = sum(p.numel() for p in self.model.parameters())
        self.train_model = torch.compile(self.model) if cfg.compile else self.model

    def validate(self) -> dict[str, float]:
        return evaluate_table(self.model, self.wd, self.val_table, self.loss_fn, self.cfg.eval_batch_size)

    def train_epoch(self, epoch: int, global_step: int, logger, progress: bool) -> tuple[dict[str, float], int, int]:
        """One epoch of the balanced sampler's draws: ``(mean train loss terms, windows seen,
        global step)``; every epoch reseeds from ``(seed, epoch)`` so a resumed run retraces."""
        from tqdm.auto import tqdm

        cfg, wd = self.cfg, self.wd
        torch.manual_seed(cfg.seed * 100_003 + epoch)
        self.sampler.set_epoch(epoch)
        order = torch.as_tensor(list(iter(self.sampler)))
        self.model.train()
        sums = {"loss": 0.0, "huber": 0.0, "speed": 0.0, "direction": 0.0}
        n_seen = 0
        inner = tqdm(range(self.steps_per_epoch), desc=f"epoch {epoch}", unit="step", leave=False, disable=not progress)
        for step in inner:
            idx = order[step * cfg.batch_size : (step + 1) * cfg.batch_size]
            x, y = self.train_ds.batch(idx)
            y = wd.label_stats(y)
            if cfg.input_noise_std > 0:
                x = x + cfg.input_noise_std * torch.randn_like(x)
            loss, terms = self.loss_fn(self.train_model(x), y)
            self.opt.zero_grad(set_to_none=True)
            loss.backward()
            if cfg.grad_clip_norm:
                torch.nn.utils.clip_grad_norm_(self.model.parameters(), cfg.grad_clip_norm)
            self.opt.step()
            self.sched.step()
            global_step += 1
            b = idx.numel()
            n_seen += b
            sums["loss"] += float(loss.detach()) * b
            for k, v in terms.items():
                sums[k] += float(v) * b
            if cfg.log_every_steps and global_step % cfg.log_every_steps == 0:
                logger.log_scalar("train/step_loss", float(loss.detach()), step=global_step)
            if progress and step % 20 == 0:
                inner.set_postfix(loss=f"{float(loss.detach()):.4f}")
        return {k: v / max(n_seen, 1) for k, v in sums.items()}, n_seen, global_step


def _epoch_row(epoch: int, lr: float, train: dict, val: dict, n_seen: int, train_time: float, t_epoch: float, wall: float) -> dict:
    return {
        "epoch": epoch,
        "lr": lr,
        **{f"train_{k}": v for k, v in train.items()},
        **{f"val_{k}": v for k, v in headline(val).items()},
        "train_windows_per_s": n_seen / train_time,
        "epoch_time_s": time.perf_counter() - t_epoch,
        "wall_time_s": wall,
    }


def _report_epoch(epoch: int, row: dict, train: dict, val: dict, n_seen: int, train_time: float, improved: bool, logger) -> None:
    from tqdm.auto import tqdm

    for k, v in row.items():
        if k != "epoch":
            logger.log_scalar(k.replace("train_", "train/", 1).replace("val_", "val/", 1), float(v), step=epoch)
    tqdm.write(
        f"epoch {epoch}: train loss {train['loss']:.4f}, val loss {val['loss']:.4f}, val per-window RMSE "
        f"{val['per_window_vector_rmse']:.3f} m/s, dir MAE {val['direction_mae_deg']:.2f} deg, per-flight "
        f"{val.get('per_flight_vector_rmse', float('nan')):.3f} m/s, {n_seen / train_time:.0f} windows/s, lr {row['lr']:.2e}"
        + (" *" if improved else "")
    )


def _finish(ed: EstimatorData, cfg: TrainConfig, trainer: _Trainer, run: _Progress, best_path: Path, out: Path,
            train_wall: float, logger) -> tuple[EstimatorBundle, dict]:
    """The best checkpoint's test metrics go into its manifest; it is written to ``out``."""
    wd = ed.windows
    bundle = EstimatorBundle.load(best_path, expect_channels=tuple(wd.channels))
    t_test = time.perf_counter()
    test_table = strided_table(wd, "test", cfg.test_stride)
    test = evaluate_table(bundle.model, wd, test_table, trainer.loss_fn, cfg.eval_batch_size) if test_table.shape[0] else {}
    test_time = time.perf_counter() - t_test
    manifest = dict(bundle.manifest)
    manifest.update(
        epochs_run=len(run.history),
        history_tail=run.history[-3:],
        test_stride=cfg.test_stride or wd.stride,
        metrics={
            **headline(test),
            "split": "test",
            "wall_time_s": round(train_wall, 1),
            "test_eval_time_s": round(test_time, 1),
            "best_epoch": run.best_epoch,
        },
    )
    bundle.manifest = manifest
    bundle.save(out)
    for k, v in headline(test).items():
        logger.log_scalar(f"test/{k}", float(v), step=run.best_epoch)
    return bundle, test


def train_estimator(
    ed: EstimatorData,
    cfg: TrainConfig,
    out: str | os.PathLike,
    *,
    resume: bool = False,
    overwrite: bool = False,
    log_dir: str | os.PathLike = "runs/estimator",
    exp_name: str | None = None,
    progress: bool = True,
    command: str | None = None,
    stop_after_epochs: int | None = None,
) -> EstimatorTrainResult:
    """Train on ``ed``'s training split, select on validation, write the best bundle to ``out``.

    ``stop_after_epochs`` ends this call after that many epochs (as an interruption would, the
    resume state stays unfinished; tests use it to check that resuming retraces the run)."""
    if cfg.regime != ed.regime:
        raise ValueError(f"TrainConfig.regime={cfg.regime!r} but the dataset is {ed.regime!r}")
    wanted = {"window": cfg.window, "train_fraction": cfg.train_fraction, "trailing_windows": list(cfg.trailing_windows)}
    prepared = {k: ed.info.get(k) for k in wanted}
    if prepared != wanted:
        raise ValueError(f"the dataset was prepared with {prepared} but TrainConfig asks for {wanted}: "
                         "load it with load_estimator_data(..., window=, trailing_windows=, train_fraction=) of the config")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    # one writer per checkpoint: its resume state and its best-so-far model belong to the run too
    with OutputLock(out, "estimator checkpoint", "wait for it to finish, or choose another out (--out)"):
        state_path = resume_path(out, log_dir)
        Path(log_dir).mkdir(parents=True, exist_ok=True)
        state = _resume_state(ed, cfg, out, state_path, resume, overwrite)
        return _train(ed, cfg, out, state_path, state, Path(log_dir), exp_name, progress, command, stop_after_epochs)


def _train(ed: EstimatorData, cfg: TrainConfig, out: Path, state_path: Path, state: dict | None, log_dir: Path,
           exp_name: str | None, progress: bool, command: str | None, stop_after_epochs: int | None) -> EstimatorTrainResult:
    """:func:`train_estimator`'s run, from ``state`` (None: a new run), under its lock."""
    from torchrl.record import CSVLogger
    from tqdm.auto import tqdm

    wd = ed.windows
    trainer = _Trainer(wd, cfg)
    run = _Progress()
    if state is not None:
        trainer.load_state_dict(state)
        run = _Progress(state["history"], state["best_val"], state["best_epoch"], state["bad_epochs"],
                        state["epoch"] + 1, state["wall_time_s"], state.get("initial_val"))
        exp_name = state["exp_name"]
        truncate_scalar_logs(log_dir / exp_name / "scalars", _logged_through(state, trainer.steps_per_epoch))
    if exp_name is None:
        exp_name = f"estimator_{cfg.regime}_{time.strftime('%Y%m%d-%H%M%S')}_{os.getpid()}"
    logger = CSVLogger(exp_name=exp_name, log_dir=str(log_dir))
    best_path = Path(log_dir) / exp_name / "best.pt"  # best so far; copied to ``out`` at the end
    best_path.parent.mkdir(parents=True, exist_ok=True)

    base_manifest = {
        "command": command,
        "regime": cfg.regime,
        "schema": cfg.regime,
        "config": cfg.to_dict(),
        "model": asdict(trainer.mcfg),
        "parameters": trainer.n_params,
        "git_commit": git_commit(),
        "platform": platform_info(),
        "dataset": ed.info,
        "torch_version": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "exp_name": exp_name,
        "log_dir": repo_relative(Path(log_dir) / exp_name),
    }
    if run.initial_val is None:  # the untrained model: the reference that training must beat
        run.initial_val = headline(trainer.validate())
        logger.log_scalar("val/loss", run.initial_val["loss"], step=-1)
        logger.log_scalar("val/per_window_vector_rmse", run.initial_val["per_window_vector_rmse"], step=-1)
    base_manifest["initial_val_metrics"] = run.initial_val
    print(
        f"{cfg.regime}: {len(wd.channels)} channels, {trainer.n_params:,} parameters; train windows "
        f"{wd.tables['train'].shape[0]:,} (drawing {trainer.per_epoch:,}/epoch, {trainer.steps_per_epoch} steps of {cfg.batch_size}), "
        f"val windows {trainer.val_table.shape[0]:,} (stride {cfg.val_stride or wd.stride}); log {Path(log_dir) / exp_name}",
        flush=True,
    )

    finished = state is not None and state.get("finished", False)
    t_start = time.perf_counter()
    epochs = range(run.start_epoch, cfg.epochs) if not finished else range(0)
    bar = tqdm(epochs, desc=f"{cfg.regime} estimator", unit="epoch", disable=not progress, initial=run.start_epoch, total=cfg.epochs)
    global_step = run.start_epoch * trainer.steps_per_epoch
    for epoch in bar:
        t_epoch = time.perf_counter()
        train, n_seen, global_step = trainer.train_epoch(epoch, global_step, logger, progress)
        train_time = time.perf_counter() - t_epoch
        val = trainer.validate()
        improved = run.update(val, epoch)
        wall = run.wall_before + time.perf_counter() - t_start
        row = _epoch_row(epoch, trainer.opt.param_groups[0]["lr"], train, val, n_seen, train_time, t_epoch, wall)
        run.history.append(row)
        if improved:
            manifest = {
                **base_manifest,
                "best_epoch": run.best_epoch,
                "epochs_run": epoch + 1,
                "val_metrics": headline(run.best),
                "metrics": {"wall_time_s": wall, "status": "training (test metrics are written at the end)"},
            }
            _make_bundle(trainer.model, wd, cfg.regime, manifest).save(best_path)
        # logged before the state is saved: a run killed in between logs the epoch again on resume
        _report_epoch(epoch, row, train, val, n_seen, train_time, improved, logger)
        stop = cfg.patience is not None and run.bad_epochs >= cfg.patience
        save_atomic(
            {
                "config": cfg.to_dict(),
                "dataset": ed.info,
                **trainer.state_dict(),
                "epoch": epoch,
                "history": run.history,
                "best_val": run.best,
                "best_epoch": run.best_epoch,
                "bad_epochs": run.bad_epochs,
                "exp_name": exp_name,
                "initial_val": run.initial_val,
                "wall_time_s": wall,
                "finished": stop or epoch == cfg.epochs - 1,
            },
            state_path,
        )
        bar.set_postfix(val_rmse=f"{val['per_window_vector_rmse']:.3f}", best=f"{run.best['per_window_vector_rmse']:.3f}@{run.best_epoch}")
        if stop:
            print(f"early stop at epoch {epoch}: no validation improvement for {run.bad_epochs} epochs", flush=True)
            break
        if stop_after_epochs is not None and epoch + 1 - run.start_epoch >= stop_after_epochs and epoch < cfg.epochs - 1:
            bar.close()
            return EstimatorTrainResult(None, run.history, run.best_epoch, run.best, {}, wall, out, exp_name, run.initial_val)
    bar.close()
    train_wall = run.wall_before + time.perf_counter() - t_start
    bundle, test = _finish(ed, cfg, trainer, run, best_path, out, train_wall, logger)
    return EstimatorTrainResult(bundle, run.history, run.best_epoch, run.best, test, train_wall, out, exp_name, run.initial_val)
