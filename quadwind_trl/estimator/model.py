"""The attention-GRU wind estimator network (paper, Section "Architecture").

A unidirectional GRU (one layer in the paper) encodes the feature window; Bahdanau additive attention, queried
by the final hidden state, pools the hidden states of that window only (causal); the context and
the final state go through a three-layer MLP head (GELU, LayerNorm, dropout) to the standardised
(north, east) mean wind.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn


@dataclass(frozen=True)
class EstimatorConfig:
    in_channels: int
    hidden: int = 128  # paper
    attention_dim: int = 128  # paper
    head_hidden: tuple[int, int] = (128, 64)
    gru_layers: int = 1  # paper: a single layer
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
        self.gru = nn.GRU(cfg.in_channels, cfg.hidden, num_layers=cfg.gru_layers, batch_first=True)
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
