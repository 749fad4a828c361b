"""The PPO update: GAE on a collected batch, then epochs of minibatch ClipPPO steps.

The frozen estimator lives in the env's ``WindEstimate`` transform as a plain attribute: the
optimiser is built from ``loss.parameters()`` (actor + critic only), and :meth:`PPOUpdate.check_frozen`
confirms at start-up that no estimator parameter is among them.
"""
from __future__ import annotations

import contextlib

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.modules import GRUModule, ProbabilisticActor, ValueOperator, set_recurrent_mode
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from ..keys import RECURRENT_KEY
from ..manifest import CheckpointParts
from .config import PPOConfig
from .reward_scale import ReturnScale
from .value_norm import NormalizedCriticLoss, normalized_value

# what the loss reads from a collected batch (the rest, e.g. the flight record, is dropped)
BATCH_KEYS = ("observation", "action", "action_log_prob", ("next", "observation"), ("next", "reward"),
              ("next", "done"), ("next", "terminated"), ("next", "truncated"))
LOSS_METRICS = ("loss_objective", "loss_critic", "loss_entropy", "entropy", "clip_fraction", "kl_approx",
                "explained_variance")


class PPOUpdate(CheckpointParts):
    """ClipPPOLoss + GAE + Adam over the actor and critic: ``update(batch, generator)`` -> mean losses."""

    # the training checkpoint's entries (state_dict / load_state_dict)
    checkpoint_parts = {"policy": "actor", "value": "value", "optimizer": "optim"}

    def __init__(self, actor: ProbabilisticActor, value: ValueOperator, cfg: PPOConfig):
        self.cfg = cfg
        self.actor, self.value = actor, value
        # a critic with value normalisation (cfg.value_norm) learns standardised targets
        self.value_head = normalized_value(value)
        loss_class, head = (ClipPPOLoss, {}) if self.value_head is None else (NormalizedCriticLoss, {"value_head": self.value_head})
        self.loss = loss_class(
            actor, value,
            clip_epsilon=cfg.clip_epsilon, entropy_coeff=cfg.entropy_coeff, critic_coeff=cfg.critic_coeff,
            loss_critic_type=cfg.loss_critic_type, normalize_advantage=cfg.normalize_advantage, **head,
        )  # fmt: skip
        self.gae = GAE(gamma=cfg.gamma, lmbda=cfg.lmbda, value_network=value, average_gae=False)
        # the critic's inputs beside the actor's (an asymmetric critic's privileged ones), now and next
        extra = [k for k in value.in_keys if k != "observation"]
        self.batch_keys = BATCH_KEYS + tuple(extra) + tuple(("next", k) for k in extra)
        # a recurrent actor re-reads each row's steps in order from the hidden state collected at its start
        self.recurrent = any(isinstance(m, GRUModule) for m in actor.modules())
        if self.recurrent:
            self.batch_keys += (RECURRENT_KEY, "is_init")
        self.params = list(self.loss.parameters())
        self.optim = torch.optim.Adam(self.params, lr=cfg.lr, eps=1e-5)  # SB3's Adam eps
        self.return_scale = None
        if cfg.reward_scaling == "return_std":
            self.return_scale = ReturnScale(cfg.num_envs, cfg.gamma).to(next(value.parameters()).device)
            self.checkpoint_parts = {**self.checkpoint_parts, "return_scale": "return_scale"}

    def check_frozen(self, model: nn.Module) -> None:
        """Fail if any parameter of ``model`` (the frozen estimator) would be optimised."""
        frozen = {id(p) for p in model.parameters()}
        if any(id(p) in frozen for p in self.params):
            raise RuntimeError("estimator parameters found among the optimised parameters")

    def update(self, data: TensorDictBase, generator: torch.Generator, lr: float | None = None) -> dict[str, float]:
        """GAE on ``data`` ([N, T], time last, before flattening, as SB3), then ``cfg.epochs``
        passes of shuffled minibatches at learning rate ``lr`` (default ``cfg.lr``); returns each
        loss term and the grad norm averaged over the minibatches."""
        cfg = self.cfg
        for group in self.optim.param_groups:  # set every update, so a resumed run follows the schedule
            group["lr"] = cfg.lr if lr is None else lr
        batch = data.select(*self.batch_keys)
        with torch.no_grad():
            if self.return_scale is not None:
                self.return_scale(batch)  # the select's leaves are the collector's: set, not written in place
            self.gae(batch)
            if self.value_head is not None:  # this batch's targets join the statistics; the critic's values stay
                self.value_head.update(batch["value_target"])
        if self.recurrent:  # minibatches of whole rows [rows, T], run as sequences (check_recurrent: whole rows fit)
            units, per_minibatch, mode = batch, cfg.minibatch // batch.shape[-1], set_recurrent_mode(True)
        else:  # minibatches of single steps
            units, per_minibatch, mode = batch.reshape(-1), cfg.minibatch, contextlib.nullcontext()
        sums: dict[str, torch.Tensor] = {}  # summed on the device: one sync per update
        steps = 0
        for _ in range(cfg.epochs):
            for idx in torch.randperm(units.batch_size[0], generator=generator).split(per_minibatch):
                with mode:
                    out = self.loss(units[idx])
                total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
                self.optim.zero_grad(set_to_none=True)
                total.backward()
                grad_norm = torch.nn.utils.clip_grad_norm_(self.params, cfg.max_grad_norm)
                self.optim.step()
                for k in LOSS_METRICS:
                    if k in out.keys():
                        sums[k] = sums.get(k, 0.0) + out[k].detach().mean()
                sums["grad_norm"] = sums.get("grad_norm", 0.0) + grad_norm.detach()
                steps += 1
        out = {k: float(v) / steps for k, v in sums.items()}
        if self.return_scale is not None:
            out["return_std"] = float(self.return_scale.std)
        if self.value_head is not None:  # the statistics the critic's targets are standardised by
            out["value_target_mean"] = float(self.value_head.norm.mean)
            out["value_target_std"] = float(self.value_head.norm.scale())
        return out

