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
  per run, reused on resume so the curves continue).

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
from typing import Any

import torch
from torch import Tensor

from ..data.generate import load_dataset
from ..data.windows import SPLIT_FRACTIONS, WindowedData, compute_features, prepare_windows, window_table
from ..evaluation.estimation import estimation_metrics
from ..manifest import git_commit, repo_relative, save_atomic
from .checkpoint import EstimatorBundle
from .features import make_extractor
from .loss import EstimatorLoss, EstimatorLossConfig
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

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        d = dict(d)
        d["loss"] = EstimatorLossConfig(**d.get("loss", {}))
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
    """A small run for smoke tests: a few short epochs at batch 64, dense validation."""
    base = full_config(regime)
    cfg = replace(
        base, epochs=8, windows_per_epoch=1024, batch_size=64, warmup_epochs=0.5, val_stride=None, patience=None
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


def load_estimator_data(
    path: str | os.PathLike, regime: str, *, quick: bool = False, progress: bool = True, fractions=SPLIT_FRACTIONS
) -> EstimatorData:
    """Load a generated dataset, compute (or load the cached) features of ``regime``'s schema
    into ``path/features_<regime>.memmap`` and prepare the windows.

    With ``quick`` and a dataset too small for the 70/15/15 split to give every split a case
    (fewer than about 7 cases), the cases are split in thirds instead."""
    path = Path(path)
    data, manifest = load_dataset(path)
    if manifest["regime"] != regime:
        raise ValueError(f"{path} is a {manifest['regime']!r} dataset, not {regime!r} (--regime)")
    fx = make_extractor(regime)
    feats = compute_features(data["record"], fx, out=path / f"features_{regime}.memmap", progress=progress)
    wd = prepare_windows(data, manifest, feats, fx.channels, fractions=fractions)
    if quick and any(wd.tables[s].shape[0] == 0 for s in ("train", "val", "test")):
        fractions = QUICK_FRACTIONS
        wd = prepare_windows(data, manifest, feats, fx.channels, fractions=fractions)
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
        "split_fractions": list(fractions),
        "split_cases": {k: int(v.numel()) for k, v in wd.split_cases.items()},
        "split_windows": {k: int(v.shape[0]) for k, v in wd.tables.items()},
        "stride": wd.stride,
    }
    return EstimatorData(windows=wd, data=data, manifest=manifest, info=info)


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


@dataclass
class TrainResult:
    bundle: EstimatorBundle
    history: list[dict]
    best_epoch: int
    best_val: dict
    test: dict
    wall_time_s: float
    out: Path
    exp_name: str
    initial_val: dict | None = None  # validation metrics of the untrained model


def _make_bundle(model: AttentionGRUEstimator, wd: WindowedData, schema: str, manifest: dict) -> EstimatorBundle:
    frozen = copy.deepcopy(model).eval().requires_grad_(False)
    return EstimatorBundle(
        model=frozen,
        schema=schema,
        channels=tuple(wd.channels),
        feature_mean=wd.feature_stats.mean.clone(),
        feature_std=wd.feature_stats.std.clone(),
        label_mean=wd.label_stats.mean.clone(),
        label_std=wd.label_stats.std.clone(),
        manifest=manifest,
    )


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
) -> TrainResult:
    """Train on ``ed``'s training split, select on validation, write the best bundle to ``out``.

    ``stop_after_epochs`` ends this call after that many epochs (as an interruption would, the
    resume state stays unfinished; tests use it to check that resuming retraces the run)."""
    from torchrl.record import CSVLogger
    from tqdm.auto import tqdm

    wd = ed.windows
    if cfg.regime != ed.regime:
        raise ValueError(f"TrainConfig.regime={cfg.regime!r} but the dataset is {ed.regime!r}")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    state_path = resume_path(out, log_dir)
    Path(log_dir).mkdir(parents=True, exist_ok=True)
    state = None
    if resume:
        if not state_path.exists():
            raise FileNotFoundError(f"--resume: no resume state at {state_path}")
        state = torch.load(state_path, map_location="cpu", weights_only=False)
        saved = TrainConfig.from_dict(state["config"])
        if saved != cfg:
            diff = {k: (v, getattr(cfg, k)) for k, v in saved.to_dict().items() if v != cfg.to_dict()[k]}
            raise ValueError(f"--resume: the configuration differs from the interrupted run's: {diff}")
        if state["dataset"]["manifest_sha256"] != ed.info["manifest_sha256"]:
            raise ValueError("--resume: the dataset differs from the interrupted run's (manifest hash)")
    elif out.exists() and not overwrite:
        raise FileExistsError(f"{out} exists: pass overwrite=True (--overwrite) to replace it")
    elif state_path.exists() and not overwrite:
        raise FileExistsError(f"an interrupted run writing {out} left {state_path}: pass resume=True (--resume) or overwrite=True (--overwrite)")
    elif state_path.exists():  # overwrite: the stale state must not be resumed later
        state_path.unlink()

    torch.manual_seed(cfg.seed)
    mcfg = EstimatorConfig(
        in_channels=len(wd.channels), feature_dropout=cfg.feature_dropout, dropout=cfg.head_dropout, window=wd.window
    )
    model = AttentionGRUEstimator(mcfg)
    loss_fn = EstimatorLoss(wd.label_stats.mean, wd.label_stats.std, cfg.loss)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    train_table = wd.tables["train"]
    per_epoch = cfg.windows_per_epoch or train_table.shape[0]
    steps_per_epoch = math.ceil(per_epoch / cfg.batch_size)
    total_steps = steps_per_epoch * cfg.epochs
    warmup = int(round(cfg.warmup_epochs * steps_per_epoch))
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: lr_factor(s, warmup, total_steps, cfg.min_lr_ratio))
    sampler = wd.sampler("train", seed=cfg.seed, num_samples=per_epoch)
    train_ds = wd.dataset("train")
    val_table = strided_table(wd, "val", cfg.val_stride)
    n_params = sum(p.numel() for p in model.parameters())

    history: list[dict] = []
    best = {"per_window_vector_rmse": math.inf}
    best_epoch, bad_epochs, start_epoch, wall_before = -1, 0, 0, 0.0
    initial_val = None
    if state is not None:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
        history, best, best_epoch = state["history"], state["best_val"], state["best_epoch"]
        bad_epochs, start_epoch, wall_before = state["bad_epochs"], state["epoch"] + 1, state["wall_time_s"]
        exp_name, initial_val = state["exp_name"], state.get("initial_val")
    if exp_name is None:
        exp_name = f"estimator_{cfg.regime}_{time.strftime('%Y%m%d-%H%M%S')}_{os.getpid()}"
    logger = CSVLogger(exp_name=exp_name, log_dir=str(log_dir))
    best_path = Path(log_dir) / exp_name / "best.pt"  # best so far; copied to ``out`` at the end
    best_path.parent.mkdir(parents=True, exist_ok=True)
    train_model = torch.compile(model) if cfg.compile else model

    base_manifest = {
        "command": command,
        "regime": cfg.regime,
        "schema": cfg.regime,
        "config": cfg.to_dict(),
        "model": asdict(mcfg),
        "parameters": n_params,
        "git_commit": git_commit(),
        "dataset": ed.info,
        "torch_version": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "exp_name": exp_name,
        "log_dir": str(Path(log_dir) / exp_name),
    }
    if initial_val is None:  # the untrained model: the reference that training must beat
        initial_val = headline(evaluate_table(model, wd, val_table, loss_fn, cfg.eval_batch_size))
        base_manifest["initial_val_metrics"] = initial_val
        logger.log_scalar("val/loss", initial_val["loss"], step=-1)
        logger.log_scalar("val/per_window_vector_rmse", initial_val["per_window_vector_rmse"], step=-1)
    base_manifest["initial_val_metrics"] = initial_val
    print(
        f"{cfg.regime}: {len(wd.channels)} channels, {n_params:,} parameters; train windows "
        f"{train_table.shape[0]:,} (drawing {per_epoch:,}/epoch, {steps_per_epoch} steps of {cfg.batch_size}), "
        f"val windows {val_table.shape[0]:,} (stride {cfg.val_stride or wd.stride}); log {Path(log_dir) / exp_name}",
        flush=True,
    )

    finished = state is not None and state.get("finished", False)
    t_start = time.perf_counter()
    epochs = range(start_epoch, cfg.epochs) if not finished else range(0)
    bar = tqdm(epochs, desc=f"{cfg.regime} estimator", unit="epoch", disable=not progress, initial=start_epoch, total=cfg.epochs)
    global_step = start_epoch * steps_per_epoch
    for epoch in bar:
        t_epoch = time.perf_counter()
        torch.manual_seed(cfg.seed * 100_003 + epoch)
        sampler.set_epoch(epoch)
        order = torch.as_tensor(list(iter(sampler)))
        model.train()
        sums = {"loss": 0.0, "huber": 0.0, "speed": 0.0, "direction": 0.0}
        n_seen = 0
        inner = tqdm(range(steps_per_epoch), desc=f"epoch {epoch}", unit="step", leave=False, disable=not progress)
        for step in inner:
            idx = order[step * cfg.batch_size : (step + 1) * cfg.batch_size]
            x, y = train_ds.batch(idx)
            y = wd.label_stats(y)
            if cfg.input_noise_std > 0:
                x = x + cfg.input_noise_std * torch.randn_like(x)
            loss, terms = loss_fn(train_model(x), y)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if cfg.grad_clip_norm:
                torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip_norm)
            opt.step()
            sched.step()
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
        train_time = time.perf_counter() - t_epoch
        train = {k: v / max(n_seen, 1) for k, v in sums.items()}
        val = evaluate_table(model, wd, val_table, loss_fn, cfg.eval_batch_size)
        improved = val["per_window_vector_rmse"] < best["per_window_vector_rmse"]
        if improved:
            best, best_epoch, bad_epochs = val, epoch, 0
        else:
            bad_epochs += 1
        wall = wall_before + time.perf_counter() - t_start
        row = {
            "epoch": epoch,
            "lr": opt.param_groups[0]["lr"],
            **{f"train_{k}": v for k, v in train.items()},
            **{f"val_{k}": v for k, v in headline(val).items()},
            "train_windows_per_s": n_seen / train_time,
            "epoch_time_s": time.perf_counter() - t_epoch,
            "wall_time_s": wall,
        }
        history.append(row)
        if improved:
            manifest = {
                **base_manifest,
                "best_epoch": best_epoch,
                "epochs_run": epoch + 1,
                "val_metrics": headline(best),
                "metrics": {"wall_time_s": wall, "status": "training (test metrics are written at the end)"},
            }
            _make_bundle(model, wd, cfg.regime, manifest).save(best_path)
        stop = cfg.patience is not None and bad_epochs >= cfg.patience
        save_atomic(
            {
                "config": cfg.to_dict(),
                "dataset": ed.info,
                "model": model.state_dict(),
                "optimizer": opt.state_dict(),
                "scheduler": sched.state_dict(),
                "epoch": epoch,
                "history": history,
                "best_val": best,
                "best_epoch": best_epoch,
                "bad_epochs": bad_epochs,
                "exp_name": exp_name,
                "initial_val": initial_val,
                "wall_time_s": wall,
                "finished": stop or epoch == cfg.epochs - 1,
            },
            state_path,
        )
        for k, v in row.items():
            if k != "epoch":
                logger.log_scalar(k.replace("train_", "train/", 1).replace("val_", "val/", 1), float(v), step=epoch)
        tqdm.write(
            f"epoch {epoch}: train loss {train['loss']:.4f}, val loss {val['loss']:.4f}, val per-window RMSE "
            f"{val['per_window_vector_rmse']:.3f} m/s, dir MAE {val['direction_mae_deg']:.2f} deg, per-flight "
            f"{val.get('per_flight_vector_rmse', float('nan')):.3f} m/s, {n_seen / train_time:.0f} windows/s, lr {row['lr']:.2e}"
            + (" *" if improved else "")
        )
        bar.set_postfix(val_rmse=f"{val['per_window_vector_rmse']:.3f}", best=f"{best['per_window_vector_rmse']:.3f}@{best_epoch}")
        if stop:
            print(f"early stop at epoch {epoch}: no validation improvement for {bad_epochs} epochs", flush=True)
            break
        if stop_after_epochs is not None and epoch + 1 - start_epoch >= stop_after_epochs and epoch < cfg.epochs - 1:
            bar.close()
            return TrainResult(None, history, best_epoch, best, {}, wall, out, exp_name, initial_val)
    bar.close()
    train_wall = wall_before + time.perf_counter() - t_start

    # final: the best checkpoint's test metrics go into its manifest
    bundle = EstimatorBundle.load(best_path, expect_channels=tuple(wd.channels))
    t_test = time.perf_counter()
    test_table = strided_table(wd, "test", cfg.test_stride)
    test = evaluate_table(bundle.model, wd, test_table, loss_fn, cfg.eval_batch_size) if test_table.shape[0] else {}
    test_time = time.perf_counter() - t_test
    manifest = dict(bundle.manifest)
    manifest.update(
        epochs_run=len(history),
        history_tail=history[-3:],
        test_stride=cfg.test_stride or wd.stride,
        metrics={
            **headline(test),
            "split": "test",
            "wall_time_s": round(train_wall, 1),
            "test_eval_time_s": round(test_time, 1),
            "best_epoch": best_epoch,
        },
    )
    bundle.manifest = manifest
    bundle.save(out)
    for k, v in headline(test).items():
        logger.log_scalar(f"test/{k}", float(v), step=best_epoch)
    return TrainResult(bundle, history, best_epoch, best, test, train_wall, out, exp_name, initial_val)
