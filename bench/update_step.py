"""The PPO update's minibatch step: where its time goes, and whether compiling the networks buys
any of it back (a candidate lever for training speed).

    python bench/update_step.py                  # 1 and 2 threads, eager and compiled
    python bench/update_step.py --threads 1 --steps 100

Setup: the recipe's actor and critic (``PPOConfig`` defaults: two hidden layers of 256, tanh) and
its ``PPOUpdate`` (TorchRL's ``ClipPPOLoss``, Adam, gradient clipping) on one minibatch of 512
random observations, as one step of the update's 10 x 32. Each setting runs in a fresh process
(as a training run is) after 10 warm-up steps. Settings:

* ``eager``: the update as the trainer runs it;
* ``compiled``: the actor's and the critic's MLPs wrapped in ``torch.compile`` (the networks are
  where the arithmetic is; the loss's bookkeeping around them is small, see ``mlp_share``).

Beside each: ``mlp_gflops``, the rate of the MLPs' matrix products counted as 2 flops per
multiply-add (forward, and backward to both the weights and the inputs), and ``sgemm_gflops``,
one bare ``[512, 256] x [256, 256]`` product on this machine at the same thread count: how close
the update is to the machine's matrix-product rate, which no compilation raises. One parseable
line per setting: ``update_step setting=... threads=... ms_per_step=... ms_per_update=...
mlp_gflops=... sgemm_gflops=... load_1min=...``.
"""
from __future__ import annotations

import argparse
import json
import time
from typing import Callable

import torch
from machine import in_fresh_process, load_1min, machine_line

SETTINGS = ("eager", "compiled")


def _mlp_flops(cfg, obs_dim: int, action_dim: int, batch: int) -> float:
    """Flops of one forward + backward of both MLPs (3 matrix products per layer and sample)."""
    flops = 0.0
    for out in (action_dim, 1):
        sizes = (obs_dim, *cfg.hidden, out)
        flops += sum(2.0 * a * b for a, b in zip(sizes[:-1], sizes[1:]))
    return 3.0 * batch * flops


def _sgemm_gflops(batch: int, width: int) -> float:
    a, w = torch.randn(batch, width), torch.randn(width, width)
    return 2.0 * batch * width * width / seconds_per_call(lambda: a @ w, 20, 200) / 1e9


def seconds_per_call(fn: Callable[[], object], warm: int, reps: int) -> float:
    """Mean wall seconds of ``fn()`` over ``reps`` calls after ``warm`` untimed ones."""
    for _ in range(warm):
        fn()
    t0 = time.perf_counter()
    for _ in range(reps):
        fn()
    return (time.perf_counter() - t0) / reps


def measure(setting: str, threads: int, steps: int) -> dict:
    """One setting, in this process."""
    from tensordict import TensorDict

    from quadwind_trl.keys import OBSERVATION_DIM
    from quadwind_trl.rl.config import PPOConfig
    from quadwind_trl.rl.policy import build_actor_critic
    from quadwind_trl.rl.update import PPOUpdate

    torch.set_num_threads(threads)
    torch.manual_seed(0)
    cfg = PPOConfig()
    actor, value = build_actor_critic(cfg)
    if setting == "compiled":
        # the MLP inside each TensorDictModule: the actor's net[0], the critic's whole module
        net = actor.module[0].module
        net[0] = torch.compile(net[0])
        value.module = torch.compile(value.module)
    learner = PPOUpdate(actor, value, cfg)
    batch = cfg.minibatch
    td = TensorDict({"observation": torch.randn(batch, OBSERVATION_DIM)}, [batch])
    with torch.no_grad():
        actor(td)
    td["advantage"] = torch.randn(batch, 1)
    td["value_target"] = torch.randn(batch, 1)

    def step() -> None:
        out = learner.loss(td)
        total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
        learner.optim.zero_grad(set_to_none=True)
        total.backward()
        torch.nn.utils.clip_grad_norm_(learner.params, cfg.max_grad_norm)
        learner.optim.step()

    per_step = seconds_per_call(step, 10, steps)
    # the MLPs alone, forward and backward, to say how much of the step they are
    mlps = [actor.module[0].module[0], value.module]
    x = td["observation"]

    def mlp_pass() -> None:
        sum(m(x).square().mean() for m in mlps).backward()

    per_mlp = seconds_per_call(mlp_pass, 5, steps)
    per_update = cfg.epochs * cfg.frames_per_batch // batch
    return {"setting": setting, "threads": threads, "ms_per_step": 1e3 * per_step, "ms_per_update": per_update * per_step * 1e3,
            "mlp_share": per_mlp / per_step, "mlp_gflops": _mlp_flops(cfg, OBSERVATION_DIM, 4, batch) / per_mlp / 1e9,
            "sgemm_gflops": _sgemm_gflops(batch, cfg.hidden[0]), "load_1min": load_1min()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--settings", nargs="+", choices=SETTINGS, default=list(SETTINGS))
    parser.add_argument("--steps", type=int, default=50, help="timed minibatch steps per setting")
    parser.add_argument("--one", nargs=2, help=argparse.SUPPRESS)  # SETTING THREADS: one setting in this process (internal)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(measure(args.one[0], int(args.one[1]), args.steps)))
        return
    print(machine_line(threads=max(args.threads)), flush=True)
    for threads in args.threads:
        for setting in args.settings:
            in_fresh_process("update_step", __file__, "--one", setting, str(threads), "--steps", str(args.steps))


if __name__ == "__main__":
    main()
