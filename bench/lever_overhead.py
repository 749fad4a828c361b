"""What each learning lever costs per env step (collection: policy + env with its transforms) and per
PPO update, against the recipe without levers, measured back to back in one process.

    python bench/lever_overhead.py                       # N = 64 rows, eager simulator, dob base
    python bench/lever_overhead.py --rows 64 --steps 40 --rounds 3 --update-rows 16

Each round times every setting once, in turn (so a drift of the machine's speed hits them alike);
the figure is the median over rounds. Collection: ``--steps`` decisions of the horizontal regime
(10 Hz, 10 control steps each) with the setting's actor, after one warm-up step. Update: one epoch
of :class:`~quadwind_trl.rl.update.PPOUpdate` on a batch of ``--update-rows`` x 256 decisions
collected with that setting. The estimator is an untrained one of the shipped architecture (its
cost does not depend on its weights).
"""
from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace

import torch

SETTINGS = {
    "none": {},
    "base_state (all, dob)": {"base_state_inputs": ("all",)},
    "privileged critic (12)": {"privileged_inputs": ("mean_wind", "turbulence", "true_error", "true_vel_error")},
    "memory 4": {"memory_frames": 4},
    "recurrent 64": {"recurrent_hidden": 64},
}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rows", type=int, default=64)
    p.add_argument("--steps", type=int, default=40, help="decisions timed per setting and round")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--update-rows", type=int, default=16, help="rows of 256 decisions in the timed update batch")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args()
    torch.set_num_threads(args.threads)

    from torchrl.collectors import Collector
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from quadwind_trl.estimator import untrained_estimator
    from quadwind_trl.regimes import regime_config
    from quadwind_trl.rl.cli import with_base_controller
    from quadwind_trl.rl.config import PPOConfig
    from quadwind_trl.rl.envs import RLEnvSpec, build_env
    from quadwind_trl.rl.policy import build_actor_critic, network_dims
    from quadwind_trl.rl.update import PPOUpdate

    config, base_wind = with_base_controller("horizontal", regime_config("horizontal"), "dob")
    estimator = untrained_estimator("horizontal", seed=0, config=config)
    cfg = PPOConfig(num_envs=args.update_rows, steps_per_env=256, epochs=1, minibatch=512)
    built = {}
    for name, levers in SETTINGS.items():
        spec = RLEnvSpec(config=config, base_wind_input=base_wind, num_envs=args.rows, compile_step=False, start="pattern",
                         **levers)
        torch.manual_seed(0)
        actor, value = build_actor_critic(cfg, **network_dims(spec))
        env = build_env(spec, estimator)
        td = env.reset()
        with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
            td = env.step_and_maybe_reset(actor(td))[1]  # warm-up
        # an update batch collected with this setting (its own rows; time not counted)
        small = build_env(replace(spec, num_envs=args.update_rows), estimator)
        collector = Collector(small, actor, frames_per_batch=args.update_rows * 256, total_frames=-1,
                              exploration_type=ExplorationType.RANDOM, auto_register_policy_transforms=False)
        batch = next(iter(collector))
        collector.shutdown()
        built[name] = (env, td, actor, PPOUpdate(actor, value, cfg), batch)

    collect = {name: [] for name in SETTINGS}
    update = {name: [] for name in SETTINGS}
    for _ in range(args.rounds):
        for name, (env, td, actor, learner, batch) in built.items():
            t0 = time.perf_counter()
            with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
                for _ in range(args.steps):
                    td = env.step_and_maybe_reset(actor(td))[1]
            collect[name].append((time.perf_counter() - t0) / args.steps)
            built[name] = (env, td, actor, learner, batch)
            t0 = time.perf_counter()
            learner.update(batch.clone(), torch.Generator().manual_seed(0))
            update[name].append(time.perf_counter() - t0)

    base_c, base_u = statistics.median(collect["none"]), statistics.median(update["none"])
    print(f"rows {args.rows}, {args.steps} decisions x {args.rounds} rounds, {args.threads} thread(s); update: 1 epoch on "
          f"{args.update_rows} x 256 decisions")
    print("| lever | collection ms / decision | vs none | update s / epoch | vs none |")
    print("|---|---|---|---|---|")
    for name in SETTINGS:
        c, u = statistics.median(collect[name]), statistics.median(update[name])
        print(f"| {name} | {1e3 * c:.1f} | {c / base_c:.2f}x | {u:.2f} | {u / base_u:.2f}x |")


if __name__ == "__main__":
    main()
