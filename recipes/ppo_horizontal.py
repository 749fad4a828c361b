"""Train the wind-aware residual PPO policy in the horizontal regime (paper, Section "Training
regimes"): the 5 fixed-altitude trajectories at 100 m, U in [3, 12] m/s, turbulence intensity in
[0.05, 0.25], reward weights alpha = beta = 1. Episodes start on the ground and include the climb.

    python recipes/ppo_horizontal.py                                   # full run: 1.5M decisions (10 Hz)
    python recipes/ppo_horizontal.py --estimator checkpoints/est.pt    # a given estimator
    python recipes/ppo_horizontal.py --quick --untrained-estimator     # smoke test (seconds)
    python recipes/ppo_horizontal.py --resume --out runs/ppo_horizontal

Writes ``--out`` (default ``runs/ppo_horizontal``): ``policy.pt`` + ``policy.json`` (final policy,
frozen normalisation, manifest with the last evaluation against PD), ``checkpoints/latest.pt``,
``logs/ppo/scalars/*.csv``. Settings and their paper counterparts: docs/rl.md.
"""
from quadwind_trl.rl.cli import build_parser, run

if __name__ == "__main__":
    run("horizontal", build_parser("horizontal", __doc__).parse_args())
