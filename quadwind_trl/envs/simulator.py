"""The batched simulator core: pure functions over a dict of ``[N, ...]`` state tensors.

:class:`QuadSimulator` composes the vehicle, the PD cascade, the trajectory library, the
atmosphere and the sensors. Its two methods are pure (state in, state out), so the TorchRL env,
the PD-only runner and ``torch.compile`` all drive exactly the same code.

One control step (10 ms) from state ``k`` (which already holds the wind, reference, measurements
and PD wrench *at* step ``k``):

1. residual: scale the action, smooth it, limit its slew, add it to the PD wrench;
2. allocate rotor speeds (motors off before arming) and run 5 physics substeps with the wind held;
3. at step ``k + 1``: sample the wind (advecting the frozen turbulence), the reference, the
   sensors, and the PD wrench for the next step; the reward, termination and truncation.
"""
from __future__ import annotations

import math

import torch
from tensordict import TensorDict
from torch import Tensor

from ..config import GRAVITY_M_S2, EnvConfig
from .atmosphere import Atmosphere
from .controller import ControllerParams, pd_control
from .navigation import NavigationParams, init_navigation, update_navigation
from .rotations import euler_from_rotmat, quat_from_euler, quat_to_rotmat, rotate_inverse, rotmat_from_euler
from .scenarios import SCENARIO_FIELDS
from .sensors import SensorSuite
from .trajectories import TrajectoryLibrary, registered_patterns
from .vehicle import RigidBody, VehicleParams, allocate, physics_step

_TRAJECTORY_CACHE: dict = {}


def trajectory_library(cfg: EnvConfig, device: torch.device) -> TrajectoryLibrary:
    """Trajectory tables are built once per (config, device, registered patterns) in a process:
    a pattern registered later gets new tables."""
    key = (cfg.trajectories, cfg.timing, str(device), tuple(registered_patterns().items()))
    if key not in _TRAJECTORY_CACHE:
        _TRAJECTORY_CACHE[key] = TrajectoryLibrary(
            cfg.trajectories, cfg.timing.control_dt_s, device, align_steps=cfg.timing.log_every_control_steps
        )
    return _TRAJECTORY_CACHE[key]


def merge_rows(mask: Tensor, new: dict[str, Tensor], old: dict[str, Tensor]) -> dict[str, Tensor]:
    """Row-wise ``where(mask, new, old)`` over every entry (``mask`` is bool ``[N]``)."""
    out = {}
    for key, value in new.items():
        m = mask.reshape(mask.shape + (1,) * (value.ndim - 1))
        out[key] = torch.where(m, value, old[key])
    return out


class QuadSimulator:
    def __init__(self, cfg: EnvConfig | None = None, device: torch.device | str | None = None):
        self.cfg = (cfg or EnvConfig()).validate()
        self.device = torch.device(device) if device is not None else torch.device("cpu")
        c, dev = self.cfg, self.device
        self.vehicle = VehicleParams.from_config(c.vehicle, dev)
        self.controller = ControllerParams.from_config(c.controller, c.vehicle, dev)
        self.trajectories = trajectory_library(c, dev)
        self.atmosphere = Atmosphere(c.wind, c.turbulence, dev)
        self.sensors = SensorSuite(c.sensors, c.timing.control_dt_s, dev)
        self.imu_substeps = self.sensors.imu_substeps(c.timing.control_substeps)
        self.navigation = NavigationParams.from_config(c.navigation)
        self.action_scale = torch.tensor(c.residual.action_scale, device=dev)
        self.slew_limit = torch.tensor(c.residual.slew_limit_per_step, device=dev)
        self.control_dt = c.timing.control_dt_s
        self.arm_step = self.trajectories.arm_step
        self.grace_steps = self.arm_step + int(round(c.reward.takeoff_grace_s / self.control_dt))
        self.cos_crash_tilt = math.cos(math.radians(c.reward.crash_tilt_deg))

    # --- episode start ------------------------------------------------------------------------

    def initial_state(self, scenario: TensorDict) -> dict[str, Tensor]:
        """The state at each scenario's ``start_step``: at the reference, level (with the
        reference heading), at rest relative to the reference; rotors at hover if airborne."""
        sc = {k: scenario.get(k).to(self.device) for k in SCENARIO_FIELDS}
        n = sc["traj_id"].shape[0]
        pattern_start, end_step = self.trajectories.schedule(sc["traj_id"], sc["altitude_m"])
        # a negative start_step means "at the start of the pattern" (airborne, after any climb)
        step = torch.where(sc["start_step"] < 0, pattern_start, sc["start_step"])
        ref = self.trajectories.reference(sc["traj_id"], step, pattern_start, sc["altitude_m"])
        zero = torch.zeros_like(ref.yaw)
        airborne = ref.pos[..., 2:] > 0
        hover = self.cfg.vehicle.hover_rotor_speed_rad_s
        state = {f"scenario.{k}": v for k, v in sc.items()}
        state.update(
            step=step,
            pattern_start=pattern_start,
            end_step=end_step,
            pos=ref.pos,
            pos_carry=torch.zeros_like(ref.pos),
            vel=ref.vel,
            quat=quat_from_euler(zero, zero, ref.yaw).squeeze(-2),
            omega=torch.zeros(n, 3, device=self.device),
            rotor=torch.where(airborne, hover, 0.0).expand(n, 4).clone(),
            specific_force=torch.zeros(n, 3, device=self.device),
            ff=torch.zeros(n, 4, device=self.device),
            cmd=torch.zeros(n, 4, device=self.device),
            reward=torch.zeros(n, 1, device=self.device),
            terminated=torch.zeros(n, 1, dtype=torch.bool, device=self.device),
        )
        state["specific_force"] = rotate_inverse(
            quat_to_rotmat(state["quat"]), torch.tensor([0.0, 0.0, GRAVITY_M_S2], device=self.device).expand(n, 3)
        )
        state.update({f"wind.{k}": v for k, v in self.atmosphere.init_state(sc).items()})
        state.update({f"sensor.{k}": v for k, v in self.sensors.init_state(sc["sensor_seed"]).items()})
        state = self._observe_instant(state, first=True)
        # an airborne start has been flying under the PD: report that as the last command
        state["cmd"] = torch.where(airborne & (step >= self.arm_step).unsqueeze(-1), state["pd_wrench"], 0.0)
        return state

    def reset(self, state: dict[str, Tensor] | None, scenario: TensorDict, mask: Tensor | None = None) -> dict[str, Tensor]:
        """Start the episodes of rows ``mask`` (all rows if None) from ``scenario`` (all rows);
        other rows keep their state untouched."""
        new = self.initial_state(scenario)
        if state is None or mask is None:
            return new
        return merge_rows(mask.reshape(-1), new, state)

    # --- one control step ---------------------------------------------------------------------

    def step(self, state: dict[str, Tensor], action: Tensor) -> dict[str, Tensor]:
        """Advance every row by one control step under residual ``action`` in ``[-1, 1]^4``."""
        r = self.cfg.residual
        ff_prev = state["ff"]
        target = action.clamp(-1.0, 1.0) * self.action_scale
        ff = r.smoothing * ff_prev + (1.0 - r.smoothing) * target
        ff = ff_prev + torch.maximum(torch.minimum(ff - ff_prev, self.slew_limit), -self.slew_limit)
        armed = (state["step"] >= self.arm_step).unsqueeze(-1)
        cmd = torch.where(armed, state["pd_wrench"] + ff, 0.0)  # what is applied: motors off before arming
        rotor_cmd = torch.where(armed, allocate(cmd, self.vehicle), 0.0)

        body = RigidBody(*(state[k] for k in RigidBody._fields))
        imu_sub = []  # body rate and specific force at the IMU's intermediate sample instants
        for i in range(1, self.cfg.timing.control_substeps + 1):
            body, specific_force = physics_step(
                body, rotor_cmd, state["wind_total"], self.vehicle, self.cfg.timing.physics_dt_s
            )
            if i in self.imu_substeps:
                imu_sub.append(torch.cat((body.omega, specific_force), -1))
        new = dict(state, specific_force=specific_force, **body._asdict())
        new.update(step=state["step"] + 1, ff=ff, cmd=cmd)
        new = self._observe_instant(new, first=False, imu_truth_sub=torch.stack(imu_sub, -2) if imu_sub else None)

        rw = self.cfg.reward
        err = new["pos"] - new["ref_pos"]
        reward = (
            rw.alive_bonus
            - rw.w_xy * err[..., :2].norm(dim=-1, keepdim=True)
            - rw.w_z * err[..., 2:].abs()
            - rw.w_ff * ff.norm(dim=-1, keepdim=True)
            - rw.w_dff * (ff - ff_prev).norm(dim=-1, keepdim=True)
        )
        finite = torch.stack([torch.isfinite(new[k]).all(-1) for k in ("pos", "vel", "quat", "omega")], -1).all(-1, keepdim=True)
        upright = quat_to_rotmat(new["quat"])[..., 2, 2:3] > self.cos_crash_tilt
        grounded = (new["pos"][..., 2:] <= 0.0) & (new["step"] > self.grace_steps).unsqueeze(-1)
        terminated = ~finite | ~upright | grounded
        # the shaped part of Eq. (2); the env adds the crash penalty once per decision
        new["reward"] = torch.where(finite, reward, 0.0)
        new["terminated"] = terminated
        return _sanitize(new, ~finite)

    # --- what the vehicle and the world look like at one instant --------------------------------

    def _observe_instant(
        self, state: dict[str, Tensor], first: bool, imu_truth_sub: Tensor | None = None
    ) -> dict[str, Tensor]:
        """Wind, reference, sensors and the PD wrench at the state's current step
        (``imu_truth_sub``: the IMU's true inputs at its samples inside the step just flown)."""
        wind_state = {k[5:]: v for k, v in state.items() if k.startswith("wind.")}
        mean, total, wind_state = self.atmosphere.sample(wind_state, state["pos"], self.control_dt)
        ref = self.trajectories.reference(
            state["scenario.traj_id"], state["step"], state["pattern_start"], state["scenario.altitude_m"]
        )
        rot = quat_to_rotmat(state["quat"])
        euler = euler_from_rotmat(rot)
        truth = torch.cat(
            (state["pos"], state["vel"], state["pos"][..., 2:], euler, state["omega"], state["specific_force"]), -1
        )
        sensor_state = {k[7:]: v for k, v in state.items() if k.startswith("sensor.")}
        force = torch.ones_like(state["step"], dtype=torch.bool).unsqueeze(-1) if first else None
        meas, sensor_state = self.sensors.measure(sensor_state, truth, state["step"], force=force,
                                                 imu_truth_sub=imu_truth_sub)

        out = dict(state)
        feedback = self.cfg.controller.feedback
        if feedback == "truth":
            nav = (state["pos"], state["vel"], rot, state["omega"])
            out.update({"nav.pos": state["pos"], "nav.vel": state["vel"],
                        "nav.baro_offset": torch.zeros_like(state["pos"][..., 2:])})
        else:
            if feedback == "sensors":
                estimate = {"pos": torch.cat((meas[..., 0:2], meas[..., 6:7]), -1), "vel": meas[..., 3:6],
                            "baro_offset": torch.zeros_like(meas[..., 6:7])}
            elif first:
                estimate = init_navigation(meas)
            else:
                estimate = update_navigation(
                    {"pos": state["nav.pos"], "vel": state["nav.vel"], "baro_offset": state["nav.baro_offset"]},
                    meas,
                    sensor_state["imu_mean"][..., 3:],
                    self.sensors.ticks(state["step"], 0),
                    self.sensors.ticks(state["step"], 6),
                    self.navigation,
                    self.control_dt,
                )
            out.update({f"nav.{k}": v for k, v in estimate.items()})
            nav = (estimate["pos"], estimate["vel"], rotmat_from_euler(meas[..., 7:10]), meas[..., 10:13])
        pd = pd_control(*nav, ref.pos, ref.vel, ref.acc, ref.jerk, ref.yaw, ref.yaw_rate, self.controller)

        out.update({f"wind.{k}": v for k, v in wind_state.items()})
        out.update({f"sensor.{k}": v for k, v in sensor_state.items()})
        out.update(
            wind_mean=mean,
            wind_total=total,
            ref_pos=ref.pos,
            ref_vel=ref.vel,
            ref_acc=ref.acc,
            ref_yaw=ref.yaw,
            meas=meas,
            pd_wrench=pd.wrench,
            tilt_cmd=pd.tilt_cmd,
            tilt_saturated=pd.tilt_saturated,
        )
        return out


def _sanitize(state: dict[str, Tensor], broken: Tensor) -> dict[str, Tensor]:
    """Rows whose physics went non-finite are parked at their reference, level and at rest, so
    nothing non-finite leaves the simulator (they are terminated in the same step). Branch-free:
    no host synchronisation in the step."""
    level = torch.zeros_like(state["quat"])
    level[..., 0] = 1.0
    fixes = {
        "pos": state["ref_pos"],
        "pos_carry": torch.zeros_like(state["pos_carry"]),
        "vel": torch.zeros_like(state["vel"]),
        "quat": level,
        "omega": torch.zeros_like(state["omega"]),
        "specific_force": torch.zeros_like(state["specific_force"]),
    }
    out = dict(state)
    for key, value in fixes.items():
        out[key] = torch.where(broken, value, state[key])
    for key in ("meas", "pd_wrench", "cmd", "ff", "wind_total", "wind_mean"):
        out[key] = torch.where(broken, 0.0, state[key].nan_to_num())
    return out
