"""The attention-GRU wind estimator (paper, Section "Architecture") and its checkpoint bundle.

A single-layer unidirectional GRU encodes the feature window; Bahdanau additive attention, queried
by the final hidden state, pools the hidden states of that window only (causal); the context and
the final state go through a three-layer MLP head (GELU, LayerNorm, dropout) to the standardised
(north, east) mean wind.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from torch import Tensor, nn

from ..validation import load_checkpoint


@dataclass(frozen=True)
class EstimatorConfig:
    in_channels: int
    hidden: int = 128  # paper
    attention_dim: int = 128  # paper
    head_hidden: tuple[int, int] = (128, 64)
    dropout: float = 0.2  # paper (head)
    feature_dropout: float = 0.0  # paper: 0.1 for the vertical model
    window: int = 60  # paper: 6 s at 10 Hz


class AdditiveAttention(nn.Module):
    """Bahdanau attention: ``score_t = v^T tanh(W_k h_t + W_q q)`` over the window's states."""

    def __init__(self, hidden: int, attention_dim: int):
        super().__init__()
        self.key = nn.Linear(hidden, attention_dim)
        self.query = nn.Linear(hidden, attention_dim)
        self.score = nn.Linear(attention_dim, 1)

    def forward(self, states: Tensor, query: Tensor) -> tuple[Tensor, Tensor]:
        energy = torch.tanh(self.key(states) + self.query(query).unsqueeze(-2))
        weights = torch.softmax(self.score(energy).squeeze(-1), dim=-1)  # [B, T]
        return (weights.unsqueeze(-1) * states).sum(-2), weights


class AttentionGRUEstimator(nn.Module):
    """``[B, T, C]`` standardised features -> ``[B, 2]`` standardised (north, east) mean wind."""

    def __init__(self, cfg: EstimatorConfig):
        super().__init__()
        self.cfg = cfg
        self.feature_dropout = nn.Dropout(cfg.feature_dropout)
        self.gru = nn.GRU(cfg.in_channels, cfg.hidden, num_layers=1, batch_first=True)
        self.attention = AdditiveAttention(cfg.hidden, cfg.attention_dim)
        h1, h2 = cfg.head_hidden
        self.head = nn.Sequential(
            nn.Linear(2 * cfg.hidden, h1),
            nn.LayerNorm(h1),
            nn.GELU(),
            nn.Dropout(cfg.dropout),
            nn.Linear(h1, h2),
            nn.LayerNorm(h2),
            nn.GELU(),
            nn.Dropout(cfg.dropout),
            nn.Linear(h2, 2),
        )

    def forward(self, features: Tensor) -> Tensor:
        states, last = self.gru(self.feature_dropout(features))
        last = last[-1]
        context, _ = self.attention(states, last)
        return self.head(torch.cat((context, last), -1))


@dataclass
class EstimatorBundle:
    """A trained estimator with everything needed to use it on raw features.

    ``schema`` names the feature representation (``"horizontal"`` / ``"vertical"``) and
    ``channels`` its channel names: loading into a pipeline with other channels fails loudly.
    """

    model: AttentionGRUEstimator
    schema: str
    channels: tuple[str, ...]
    feature_mean: Tensor  # [C]
    feature_std: Tensor  # [C]
    label_mean: Tensor  # [2] (north, east), m/s
    label_std: Tensor  # [2]
    ema_tau_s: float = 3.0  # paper: the deployed post-filter time constant
    manifest: dict = field(default_factory=dict)

    @torch.no_grad()
    def predict(self, features: Tensor) -> Tensor:
        """Raw (unstandardised) feature windows ``[B, T, C]`` -> mean wind (north, east) in m/s."""
        z = (features - self.feature_mean) / self.feature_std
        return self.model(z) * self.label_std + self.label_mean

    def to(self, device: torch.device | str) -> "EstimatorBundle":
        self.model.to(device)
        for name in ("feature_mean", "feature_std", "label_mean", "label_std"):
            setattr(self, name, getattr(self, name).to(device))
        return self

    def save(self, path: str | Path) -> None:
        """Write ``path`` (weights and statistics) and ``path.json`` (the manifest) atomically."""
        path = Path(path)
        payload = {
            "kind": "estimator",  # validation.load_checkpoint tells an estimator from a policy by it
            "config": asdict(self.model.cfg),
            "state_dict": self.model.state_dict(),
            "schema": self.schema,
            "channels": list(self.channels),
            "feature_mean": self.feature_mean.cpu(),
            "feature_std": self.feature_std.cpu(),
            "label_mean": self.label_mean.cpu(),
            "label_std": self.label_std.cpu(),
            "ema_tau_s": self.ema_tau_s,
        }
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
        cfg = payload["config"]
        cfg["head_hidden"] = tuple(cfg["head_hidden"])
        model = AttentionGRUEstimator(EstimatorConfig(**cfg))
        model.load_state_dict(payload["state_dict"])
        manifest_path = path.with_suffix(".json")
        manifest = json.loads(manifest_path.read_text()) if manifest_path.exists() else {}
        bundle = cls(
            model=model.eval().requires_grad_(False),
            schema=payload["schema"],
            channels=channels,
            feature_mean=payload["feature_mean"],
            feature_std=payload["feature_std"],
            label_mean=payload["label_mean"],
            label_std=payload["label_std"],
            ema_tau_s=float(payload["ema_tau_s"]),
            manifest=manifest,
        )
        return bundle.to(device)


CHECKPOINT_DIR = Path(__file__).resolve().parent.parent / "checkpoints"


def pretrained_estimator(regime: str, device: torch.device | str = "cpu") -> EstimatorBundle:
    """The shipped estimator for ``"horizontal"`` or ``"vertical"`` flight, by name."""
    path = CHECKPOINT_DIR / f"estimator_{regime}.pt"
    if not path.exists():
        raise FileNotFoundError(f"no shipped estimator for regime {regime!r} at {path}; train one with recipes/train_estimator.py")
    return EstimatorBundle.load(path, device=device)
