"""Reward scaling by the spread of the discounted return (SB3's ``VecNormalize(norm_reward=True)``).

The horizontal returns are dominated by a few windy episodes and the crash penalty, so the critic's
targets span two orders of magnitude over training. Dividing every reward by the running standard
deviation of the discounted return keeps the value targets near unit scale without moving the
optimum (a positive constant factor on the reward; the mean is not subtracted, which would change
the value of ending an episode). It acts on the collected batch only: the environment, its
reward and every evaluation are unchanged.

Batched: the discounted return of each sub-env is carried across batches and accumulated over the
batch's time axis; the running statistics take the whole batch at once (SB3 updates them step by
step, a difference of one batch in what the scale has seen).
"""
from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torch import nn

REWARD = ("next", "reward")
DONE = ("next", "done")


class ReturnScale(nn.Module):
    """Divide ``("next", "reward")`` of a [N, T] batch by the running std of the discounted return.

    Its buffers (the running count, mean and M2, and each sub-env's return so far) go in the
    training checkpoint, so a resumed run continues the same scale.
    """

    def __init__(self, num_envs: int, gamma: float, clip: float = 10.0, eps: float = 1e-8):
        super().__init__()
        self.gamma, self.clip, self.eps = gamma, clip, eps
        self.register_buffer("running_return", torch.zeros(num_envs))  # per sub-env, carried across batches
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))
        self.register_buffer("mean", torch.zeros((), dtype=torch.float64))
        self.register_buffer("m2", torch.zeros((), dtype=torch.float64))

    @property
    def std(self) -> torch.Tensor:
        """The running std of the discounted return (1 before any data)."""
        if self.count < 2:
            return torch.ones((), dtype=torch.float64, device=self.count.device)
        return (self.m2 / self.count).sqrt()

    @torch.no_grad()
    def forward(self, batch: TensorDictBase) -> TensorDictBase:
        """Update the statistics with ``batch``'s discounted returns and scale its rewards in place."""
        reward = batch.get(REWARD).squeeze(-1)  # [N, T]
        done = batch.get(DONE).squeeze(-1)
        if reward.shape[0] != self.running_return.shape[0]:
            raise ValueError(f"ReturnScale: batch of {reward.shape[0]} sub-envs, expected {self.running_return.shape[0]} "
                             "(the batch must be [num_envs, steps], time last)")
        returns = torch.empty_like(reward)
        ret = self.running_return
        for t in range(reward.shape[1]):  # a [N] recurrence over time: cheap next to the update
            ret = self.gamma * ret + reward[:, t]
            returns[:, t] = ret
            ret = torch.where(done[:, t], torch.zeros_like(ret), ret)
        self.running_return.copy_(ret)
        self._update_moments(returns.reshape(-1).double())
        scaled = (reward / (self.std.to(reward.dtype) + self.eps)).clamp(-self.clip, self.clip)
        batch.set(REWARD, scaled.unsqueeze(-1))
        return batch

    def _update_moments(self, x: torch.Tensor) -> None:
        """Chan et al.'s parallel update of (count, mean, M2) with the samples ``x``."""
        n, mean = x.numel(), x.mean()
        m2 = ((x - mean) ** 2).sum()
        total = self.count + n
        delta = mean - self.mean
        self.m2 += m2 + delta**2 * self.count * n / total
        self.mean += delta * n / total
        self.count.fill_(total)
