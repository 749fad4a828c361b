"""Checkpointed learned estimators: :class:`EstimatorBundle` (network + standardisation), the
registry of network classes a checkpoint may name, and the loaders of the shipped checkpoints.

A checkpoint names its network class in ``payload["model"]`` (a key of :data:`MODELS`); the
shipped checkpoints predate that entry and hold the attention-GRU, which is therefore the default.
A new learned network is registered with :func:`register_model` and loads with no other change.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from ..config import EnvConfig
from ..manifest import CHECKPOINT_DIR
from ..validation import load_checkpoint
from .base import WindEstimator
from .features import Schema, make_extractor
from .model import AttentionGRUEstimator, EstimatorConfig
from .ukf import WindUKF

SCHEMAS = ("horizontal", "vertical")


@dataclass(frozen=True)
class ModelEntry:
    """A network class a checkpoint can name, and its config dataclass (``module(config)``;
    the module keeps the config as ``.cfg``, whose ``window`` is the input length)."""

    module: type[nn.Module]
    config: type


MODELS: dict[str, ModelEntry] = {}
#: the network of checkpoints without a ``"model"`` entry (the shipped ones)
DEFAULT_MODEL = "attention_gru"


def register_model(name: str, module: type[nn.Module], config: type) -> None:
    """Make checkpoints with ``payload["model"] == name`` load as ``module(config(**cfg))``."""
    MODELS[name] = ModelEntry(module, config)


register_model(DEFAULT_MODEL, AttentionGRUEstimator, EstimatorConfig)


def model_name(model: nn.Module) -> str:
    """The registry name of ``model``'s class (what a saved checkpoint records)."""
    for name, entry in MODELS.items():
        if type(model) is entry.module:
            return name
    raise ValueError(f"{type(model).__name__} is not a registered estimator network; register_model() it first")


def _build_model(name: str, cfg: dict) -> nn.Module:
    if name not in MODELS:
        raise ValueError(f"estimator checkpoint model={name!r}; registered: {sorted(MODELS)}")
    entry = MODELS[name]
    # JSON/torch round trips turn tuples into lists; the config dataclasses are frozen and hashable
    cfg = {k: tuple(v) if isinstance(v, list) else v for k, v in cfg.items()}
    return entry.module(entry.config(**cfg))


@dataclass
class EstimatorBundle:
    """A trained network with everything needed to use it on raw features; implements
    :class:`~quadwind_trl.estimator.base.WindEstimator`.

    ``schema`` names the feature representation (``"horizontal"`` / ``"vertical"``) and
    ``channels`` its channel names: loading into a pipeline with other channels fails loudly.
    ``ema_tau_s`` is the post-filter time constant recorded in the checkpoint, if any: the env
    no longer reads it (``make_env(..., ema_tau_s=...)`` sets the filter), but policies trained
    before their env spec recorded ``ema_tau_s`` were trained with it
    (:func:`quadwind_trl.rl.envs.policy_env_settings`).
    """

    model: nn.Module  # standardised windows [B, T, C] -> standardised (north, east) [B, 2]
    schema: str
    channels: tuple[str, ...]
    feature_mean: Tensor  # [C]
    feature_std: Tensor  # [C]
    label_mean: Tensor  # [2] (north, east), m/s
    label_std: Tensor  # [2]
    ema_tau_s: float | None = None
    manifest: dict = field(default_factory=dict)

    def __post_init__(self):
        # a bundle is a frozen estimator: no dropout at inference, invisible to any optimiser
        self.model.eval().requires_grad_(False)

    @property
    def window(self) -> int:
        return self.model.cfg.window

    @torch.no_grad()
    def predict(self, windows: Tensor) -> Tensor:
        """Raw (unstandardised) feature windows ``[B, T, C]`` -> mean wind (north, east) in m/s."""
        z = (windows - self.feature_mean) / self.feature_std
        return self.model(z) * self.label_std + self.label_mean

    def to(self, device: torch.device | str) -> "EstimatorBundle":
        self.model.to(device)
        for name in ("feature_mean", "feature_std", "label_mean", "label_std"):
            setattr(self, name, getattr(self, name).to(device))
        return self

    def save(self, path: str | Path) -> None:
        """Write ``path`` (weights and statistics) and ``path.json`` (the manifest) atomically."""
        path = Path(path)
        payload: dict[str, Any] = {
            "kind": "estimator",  # validation.load_checkpoint tells an estimator from a policy by it
            "model": model_name(self.model),
            "config": asdict(self.model.cfg),
            "state_dict": self.model.state_dict(),
            "schema": self.schema,
            "channels": list(self.channels),
            "feature_mean": self.feature_mean.cpu(),
            "feature_std": self.feature_std.cpu(),
            "label_mean": self.label_mean.cpu(),
            "label_std": self.label_std.cpu(),
        }
        if self.ema_tau_s is not None:
            payload["ema_tau_s"] = self.ema_tau_s
        tmp = path.with_suffix(path.suffix + ".tmp")
        torch.save(payload, tmp)
        tmp.replace(path)
        manifest = path.with_suffix(".json")
        tmp = manifest.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(self.manifest, indent=2, sort_keys=True, default=str) + "\n")
        tmp.replace(manifest)

    @classmethod
    def load(
        cls, path: str | Path, expect_channels: tuple[str, ...] | None = None, device: torch.device | str = "cpu"
    ) -> "EstimatorBundle":
        path = Path(path)
        payload = load_checkpoint(path, "estimator", device)
        channels = tuple(payload["channels"])
        if expect_channels is not None and tuple(expect_channels) != channels:
            missing = [c for c in expect_channels if c not in channels]
            extra = [c for c in channels if c not in expect_channels]
            raise ValueError(
                f"estimator checkpoint {path} was trained on the {payload['schema']!r} feature schema "
                f"({len(channels)} channels), which differs from this pipeline's "
                f"({len(expect_channels)} channels; missing {missing[:5]}, unexpected {extra[:5]})"
            )
        model = _build_model(payload.get("model", DEFAULT_MODEL), payload["config"])
        model.load_state_dict(payload["state_dict"])
        manifest_path = path.with_suffix(".json")
        manifest = json.loads(manifest_path.read_text()) if manifest_path.exists() else {}
        tau = payload.get("ema_tau_s")
        bundle = cls(
            model=model,
            schema=payload["schema"],
            channels=channels,
            feature_mean=payload["feature_mean"],
            feature_std=payload["feature_std"],
            label_mean=payload["label_mean"],
            label_std=payload["label_std"],
            ema_tau_s=None if tau is None else float(tau),
            manifest=manifest,
        )
        return bundle.to(device)


def _check_schema(schema: str) -> None:
    if schema not in SCHEMAS:
        raise ValueError(f"regime={schema!r}; allowed: {SCHEMAS}")


def untrained_estimator(schema: Schema = "horizontal", seed: int = 0, config: EnvConfig | None = None) -> EstimatorBundle:
    """A seeded, randomly initialised attention-GRU with identity standardisation, for development
    and smoke tests only (its outputs are meaningless)."""
    channels = make_extractor(schema, config).channels
    gen_state = torch.random.get_rng_state()
    torch.manual_seed(seed)
    model = AttentionGRUEstimator(EstimatorConfig(in_channels=len(channels)))
    torch.random.set_rng_state(gen_state)
    c = len(channels)
    return EstimatorBundle(
        model=model,
        schema=schema,
        channels=channels,
        feature_mean=torch.zeros(c),
        feature_std=torch.ones(c),
        label_mean=torch.zeros(2),
        label_std=torch.ones(2),
        manifest={"untrained": True, "seed": seed},
    )


def default_estimator_path(regime: Schema) -> Path:
    """The shipped estimator checkpoint of ``regime``."""
    return CHECKPOINT_DIR / f"estimator_{regime}.pt"


#: model-based estimators by the name a recipe's ``--estimator`` takes in place of a checkpoint
MODEL_BASED_ESTIMATORS = ("ukf",)


def load_estimator(regime: Schema, path: str | Path | None = None, *, untrained: bool = False, seed: int = 0,
                   config: EnvConfig | None = None, device: torch.device | str = "cpu") -> WindEstimator:
    """The estimator at ``path`` (default: the shipped one for ``regime``); ``path="ukf"``: the
    model-based :class:`~quadwind_trl.estimator.ukf.WindUKF` on ``config``'s airframe (horizontal
    schema only); with ``untrained=True`` and no path, a seeded random one. Fails with a clear
    message when nothing fits."""
    _check_schema(regime)
    if path is None and untrained:
        return untrained_estimator(regime, seed, config).to(device)
    if str(path) in MODEL_BASED_ESTIMATORS:
        if regime != WindUKF.schema:
            raise ValueError(f"estimator {str(path)!r} reads the {WindUKF.schema!r} feature schema; regime={regime!r} "
                             f"has no model-based estimator (allowed: a checkpoint path)")
        return WindUKF(config=config).to(device)
    path = Path(path) if path is not None else default_estimator_path(regime)
    if not path.exists():
        raise FileNotFoundError(
            f"no estimator checkpoint at {path}. Train one (recipes/train_estimator.py --regime {regime}) "
            "and pass --estimator PATH, or pass --untrained-estimator for a smoke test (random estimator: "
            "the wind channels are then meaningless)"
        )
    bundle = EstimatorBundle.load(path, device=device)
    if bundle.schema != regime:
        raise ValueError(f"estimator checkpoint {path} is a {bundle.schema!r} estimator; regime={regime!r}")
    make_extractor(regime, config, channels=bundle.channels)  # refuses channels no extractor of this schema makes
    return bundle
