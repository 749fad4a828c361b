"""Train the wind-aware residual PPO policy in the vertical regime with the paper's four-stage
curriculum: arm at t = 1 s, climb to 600 m; U_mean in [2, 10] m/s, shear alpha in [0.08, 0.15]
coupled with U, veer +-5 deg/100 m, turbulence intensity [0.05, 0.25]; reward beta = 1 (the paper's 0.5
is --reward-w-z 0.5; docs/rl.md, "The vertical recipe, chosen").

Curriculum (cumulative; stage k starts after k quarters of the frames): vertical_climb ->
+ spiral_ascent -> + figure8_3d -> + lawnmower_scan. At each stage change the running episodes are
truncated so the new trajectory set takes effect at once.

    python recipes/ppo_vertical_curriculum.py                                 # full run: 1.5M decisions (10 Hz)
    python recipes/ppo_vertical_curriculum.py --quick --untrained-estimator   # smoke test (seconds)
    python recipes/ppo_vertical_curriculum.py --resume --out runs/ppo_vertical

Writes ``--out`` (default ``runs/ppo_vertical``); see docs/rl.md.
"""
from quadwind_trl.rl.cli import build_parser, run

if __name__ == "__main__":
    run("vertical", build_parser("vertical", __doc__).parse_args(), curriculum=True)
