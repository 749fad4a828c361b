"""The batched quadrotor simulator and its TorchRL env.

Frames and conventions, fixed once for the whole project:

* **World frame: ENU** (x east, y north, z up, metres). Altitude is ``z``. Labels and estimator
  outputs are ordered (north, east) as in the paper: ``wind_ne = (wind[..., 1], wind[..., 0])``.
* **Body frame: FLU** (x forward, y left, z up); thrust acts along body +z.
* **Attitude**: unit quaternion ``(w, x, y, z)`` rotating body to world; Euler angles are Z-Y-X
  (roll, pitch, yaw), yaw measured from east, counter-clockwise.
* **Wind direction**: meteorological, the direction the wind blows *from*, clockwise from north.
* **Time**: physics at 500 Hz, control at 100 Hz (one env step, or `TimingConfig.hold_control_steps` of them), flight record at 10 Hz; the
  integer control-step counter is the clock (``t = step * 0.01 s``).
"""
from .parallel import parallel_env
from .quad_env import QuadWindEnv, ScenarioSampler
from .ray_rows import RayRowsEnv
from .scenarios import RegimeRanges, make_scenarios, sample_regimes
from .simulator import QuadSimulator
from .trajectories import (
    HORIZONTAL,
    HOVER,
    VERTICAL,
    ClimbingPattern,
    LevelPattern,
    Pattern,
    register_trajectory,
    trajectory_id,
    trajectory_ids,
    trajectory_name,
    trajectory_names,
)

__all__ = [
    "QuadWindEnv",
    "ScenarioSampler",
    "parallel_env",
    "RayRowsEnv",
    "QuadSimulator",
    "RegimeRanges",
    "make_scenarios",
    "sample_regimes",
    "HORIZONTAL",
    "HOVER",
    "VERTICAL",
    "Pattern",
    "LevelPattern",
    "ClimbingPattern",
    "register_trajectory",
    "trajectory_names",
    "trajectory_name",
    "trajectory_id",
    "trajectory_ids",
]
