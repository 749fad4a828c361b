"""The batched simulator core: pure functions over two TensorDicts of batch ``[N]``.

``params`` holds what is fixed for an episode, written only when it starts: the scenario
(``params["scenario"]``, the fields of ``SCENARIO_FIELDS``), its schedule (``pattern_start``,
``end_step``), the atmosphere's per-episode constants (``params["wind"]``: profile, field maps,
mode phases and amplitudes or cube) and the sensor noise seed with its streams' hash keys
(``params["sensors"]``).
``state`` holds what a step changes, one sub-tensordict per concept:

* ``step`` [N]: the control-step counter; ``finite`` [N, 1]: the physics stayed finite;
* ``body``: the rigid body (``pos``, ``pos_carry``, ``vel``, ``quat``, ``omega``, ``rotor``,
  :class:`~quadwind_trl.envs.vehicle.RigidBody`) and its ``specific_force``;
* ``wind``: ``air_offset`` (the frozen field's advection), ``mean`` and ``total`` air velocity;
* ``sensors``: the instruments' packed ``bias``, ``held`` and ``imu_mean`` and the measurements
  ``meas``, a sub-tensordict of named entries (``gps_pos``, ..., :data:`~.sensors.INSTRUMENTS`);
* ``nav``: the navigation solution the PD flies on (``pos``, ``vel``, ``baro_offset``);
* ``ref``: the reference (``pos``, ``vel``, ``acc``, ``yaw``);
* ``control``: the base controller's output (``pd_wrench``, ``tilt_cmd``, ``tilt_saturated``),
  the residual ``ff`` (the applied correction: ``[N, 4]`` N and N m on the wrench, ``[N, 3]``
  m/s^2 forward, left, up on the acceleration; ``ResidualConfig.acts_on``) and the total command
  ``cmd``; with the runtime monitor on
  (``ResidualConfig.monitor``), also ``monitor_left``: its steps left of the base law alone
  (:mod:`~quadwind_trl.envs.monitor`);
* ``base`` (only for a base controller with state, e.g. integral action or a disturbance
  observer): the law's own state (:mod:`~quadwind_trl.envs.controller`).

:class:`QuadSimulator` composes the vehicle, the base controller, the trajectory library, the
atmosphere and the sensors. Its methods are pure (in, out), so the TorchRL env, the PD-only
runner and ``torch.compile`` all drive exactly the same code. Reward and termination are the
task's (:mod:`quadwind_trl.envs.task`), not the physics'.

One control step (10 ms) from state ``k`` (which already holds the wind, reference, measurements
and PD wrench *at* step ``k``):

1. residual: scale the action, smooth it, limit its slew (zero it while the runtime monitor, if
   on, holds it); on the wrench, add it to the PD wrench;
2. allocate rotor speeds (motors off before arming) and run 5 physics substeps with the wind held;
3. at step ``k + 1``: sample the wind (advecting the frozen turbulence), the reference, the
   sensors, and the PD wrench for the next step; a residual on the acceleration enters that
   wrench's outer loop, so the correction set at step ``k`` acts from step ``k + 1``, one control
   step (10 ms) later than a residual on the wrench.
"""
from __future__ import annotations

import torch
from tensordict import TensorDict, is_tensor_collection
from torch import Tensor

from ..config import GRAVITY_M_S2, EnvConfig
from ..keys import MEAS_KEY
from .atmosphere import Atmosphere
from .controller import BaseController, ControlInputs, make_base_controller
from .monitor import MonitorParams, monitor_gate
from .navigation import NavigationParams, init_navigation, update_navigation
from .operands import operands
from .rotations import (euler_from_rotmat, euler_to_rotmat, heading_to_world, quat_from_euler, quat_to_rotmat,
                        rotate_inverse)
from .scenarios import SCENARIO_FIELDS
from .sensors import SensorSuite
from .tensordicts import entry, unchecked
from .trajectories import TrajectoryLibrary, registered_patterns
from .vehicle import RigidBody, VehicleParams, allocate, physics_step, step_constants

_TRAJECTORY_CACHE: dict = {}


def trajectory_library(cfg: EnvConfig, device: torch.device) -> TrajectoryLibrary:
    """Trajectory tables are built once per (config, device, registered patterns) in a process:
    a pattern registered later gets new tables."""
    key = (cfg.trajectories, cfg.timing.control_dt_s, cfg.timing.log_every_control_steps, str(device),
           tuple(registered_patterns().items()))
    if key not in _TRAJECTORY_CACHE:
        _TRAJECTORY_CACHE[key] = TrajectoryLibrary(
            cfg.trajectories, cfg.timing.control_dt_s, device, align_steps=cfg.timing.log_every_control_steps
        )
    return _TRAJECTORY_CACHE[key]


class QuadSimulator:
    """The simulator of ``cfg`` on ``device``; ``controller`` replaces the base controller the
    config chooses (:func:`~quadwind_trl.envs.controller.make_base_controller`) by a user's own
    :class:`~quadwind_trl.envs.controller.BaseController`."""

    def __init__(self, cfg: EnvConfig | None = None, device: torch.device | str | None = None,
                 controller: BaseController | None = None):
        self.cfg = (cfg or EnvConfig()).validate()
        self.device = torch.device(device) if device is not None else torch.device("cpu")
        c, dev = self.cfg, self.device
        self.vehicle = VehicleParams.from_config(c.vehicle, dev)
        self.physics_constants = step_constants(self.vehicle, c.timing.physics_dt_s, dev)
        self._level = torch.tensor([1.0, 0.0, 0.0, 0.0], device=dev)  # the attitude a broken row is parked in
        self.controller = controller or make_base_controller(c.controller, c.vehicle, c.timing.control_dt_s, dev)
        self.on_acceleration = c.residual.acts_on == "acceleration"
        if self.on_acceleration and not getattr(self.controller, "takes_acc_correction", False):
            raise ValueError(f"ResidualConfig.acts_on='acceleration' with the base controller "
                             f"{type(self.controller).__name__}, which does not add ControlInputs.acc_correction to "
                             "its desired acceleration; allowed: a law with takes_acc_correction = True (the "
                             "CascadeController does), or acts_on='wrench'")
        self.trajectories = trajectory_library(c, dev)
        self.atmosphere = Atmosphere(c.wind, c.turbulence, dev)
        self.sensors = SensorSuite(c.sensors, c.timing.control_dt_s, dev)
        self.imu_substeps = self.sensors.imu_substeps(c.timing.control_substeps)
        self.navigation = NavigationParams.from_config(c.navigation)
        self.action_scale = torch.tensor(c.residual.scale, device=dev)
        self.slew_limit = torch.tensor(c.residual.slew, device=dev)
        # the residual smoother's weights and the unarmed command: Python numbers for a traced
        # step, tensors for the eager one (operands.py)
        self._numbers = (c.residual.smoothing, 1.0 - c.residual.smoothing, 0.0)
        self._operands = (*(torch.tensor(v, device=dev) for v in self._numbers[:2]), self.physics_constants.zero)
        self.monitor = (None if c.residual.monitor is None else
                        MonitorParams.from_config(c.residual.monitor, c.controller, self.vehicle, c.timing.control_dt_s))
        self.control_dt = c.timing.control_dt_s
        self.arm_step = self.trajectories.arm_step

    # --- episode start ------------------------------------------------------------------------

    def initial(self, scenario: TensorDict) -> tuple[TensorDict, TensorDict]:
        """``(params, state)`` at each scenario's ``start_step``: at the reference, level (with the
        reference heading), at rest relative to the reference; rotors at hover if airborne."""
        sc = TensorDict({k: scenario.get(k).to(self.device) for k in SCENARIO_FIELDS}, batch_size=scenario.batch_size)
        n = sc.batch_size[0]
        pattern_start, end_step = self.trajectories.schedule(sc["traj_id"], sc["altitude_m"])
        # a negative start_step means "at the start of the pattern" (airborne, after any climb)
        step = torch.where(sc["start_step"] < 0, pattern_start, sc["start_step"])
        ref = self.trajectories.reference(sc["traj_id"], step, pattern_start, sc["altitude_m"])
        zero = torch.zeros_like(ref.yaw)
        airborne = ref.pos[..., 2:] > 0
        hover = self.cfg.vehicle.hover_rotor_speed_rad_s
        wind_params, wind_state = self.atmosphere.init(sc)
        sensor_params, sensor_state = self.sensors.init(sc["sensor_seed"])
        params = TensorDict(scenario=sc, pattern_start=pattern_start, end_step=end_step, wind=wind_params,
                            sensors=sensor_params, batch_size=[n])
        quat = quat_from_euler(zero, zero, ref.yaw).squeeze(-2)
        gravity = torch.tensor([0.0, 0.0, GRAVITY_M_S2], device=self.device).expand(n, 3)
        body = TensorDict(
            pos=ref.pos,
            pos_carry=torch.zeros_like(ref.pos),
            vel=ref.vel,
            quat=quat,
            omega=torch.zeros(n, 3, device=self.device),
            rotor=torch.where(airborne, hover, 0.0).expand(n, 4).clone(),
            specific_force=rotate_inverse(quat_to_rotmat(quat), gravity),
            batch_size=[n],
        )
        control = TensorDict(ff=torch.zeros(n, self.cfg.residual.channels, device=self.device),
                             cmd=torch.zeros(n, 4, device=self.device),
                             batch_size=[n])
        if self.monitor is not None:  # a config constant: with the monitor off the state is as before it existed
            control["monitor_left"] = torch.zeros(n, 1, dtype=torch.int64, device=self.device)
        base = self.controller.init_state(n, self.device)
        state = TensorDict(step=step, body=body, wind=wind_state, sensors=sensor_state, control=control,
                           **({} if base is None else {"base": base}), batch_size=[n])
        # a wind feed-forward law knows no wind at an episode's first instant: the estimate comes with the first step
        no_wind = torch.zeros(n, 2, device=self.device) if self.controller.needs_wind else None
        state = self._observe_instant(params, state, first=True, wind_ne=no_wind)
        # the keys in the order :meth:`step` returns them: a compiled step is guarded on the order
        # of its input's keys, and a start in another order cost every env a second compilation
        state["finite"] = torch.ones(n, 1, dtype=torch.bool, device=self.device)
        # an airborne start has been flying under the PD: report that as the last command
        control = state["control"]
        control["cmd"] = torch.where(airborne & (step >= self.arm_step).unsqueeze(-1), control["pd_wrench"], 0.0)
        return params, state.apply(Tensor.contiguous)  # and with the step's (contiguous) strides

    def reset(
        self, params: TensorDict | None, state: TensorDict | None, scenario: TensorDict, rows: Tensor | None = None
    ) -> tuple[TensorDict, TensorDict]:
        """Start the episodes of rows ``rows`` (int64 ``[K]``; all rows if None) from ``scenario``
        (``[K]``, one row per restarted row, in that order); other rows keep their params and
        state untouched. Only the ``K`` restarted rows are computed: a row's start is a function
        of its scenario alone, so a sub-batch gives the bits the full batch would (a partial
        reset of one row costs one row, not ``N``)."""
        new_params, new_state = self.initial(scenario)
        if state is None or rows is None:
            return new_params, new_state
        return _scatter_rows(params, rows, new_params), _scatter_rows(state, rows, new_state)

    # --- one control step ---------------------------------------------------------------------

    def step(self, params: TensorDict, state: TensorDict, action: Tensor, wind_ne: Tensor | None = None) -> TensorDict:
        """The state one control step on, every row under residual ``action`` in ``[-1, 1]^C``
        (``C = ResidualConfig.channels``: 4 on the wrench, 3 on the acceleration);
        ``wind_ne`` ``[N, 2]`` (north, east, m/s): the wind estimate a wind feed-forward base
        controller flies the next instant's law on (held over the step, as the action is)."""
        ff_prev = entry(state, "control", "ff")
        target = action.clamp(-1.0, 1.0) * self.action_scale
        smoothing, one_minus_smoothing, zero = operands(self._operands, self._numbers)
        ff = smoothing * ff_prev + one_minus_smoothing * target
        ff = ff_prev + torch.maximum(torch.minimum(ff - ff_prev, self.slew_limit), -self.slew_limit)
        monitor = {}
        if self.monitor is not None:  # a config constant: off, the step runs the same ops as before the monitor
            height_error = entry(state, "nav", "pos")[..., 2:] - entry(state, "ref", "pos")[..., 2:]
            # the thrust commanded over this step: on the acceleration the base wrench already holds the
            # correction (of the step before), so the gate's zero reaches the wrench one step later
            thrust = entry(state, "control", "pd_wrench")[..., :1]
            thrust = thrust if self.on_acceleration else thrust + ff[..., :1]
            ff, monitor["monitor_left"] = monitor_gate(ff, thrust, self._cos_tilt(state), height_error,
                                                       entry(state, "control", "monitor_left"), self.monitor)
        armed = (entry(state, "step") >= self.arm_step).unsqueeze(-1)
        # what is applied (motors off before arming): on the acceleration the base wrench is the
        # command, the correction being inside its outer loop
        wrench = entry(state, "control", "pd_wrench")
        cmd = torch.where(armed, wrench if self.on_acceleration else wrench + ff, zero)
        rotor_cmd = torch.where(armed, allocate(cmd, self.vehicle), zero)

        body = RigidBody(*(entry(state, "body", k) for k in RigidBody._fields))
        wind_total = entry(state, "wind", "total")
        imu_sub = []  # what the IMU instruments read at their intermediate sample instants
        for i in range(1, self.cfg.timing.control_substeps + 1):
            body, specific_force = physics_step(body, rotor_cmd, wind_total, self.vehicle, self.cfg.timing.physics_dt_s,
                                                self.physics_constants)
            if i in self.imu_substeps:
                imu_sub.append((body.omega, specific_force))
        n = state.batch_size
        finite = torch.isfinite(torch.cat((body.pos, body.vel, body.quat, body.omega), -1)).all(-1, keepdim=True)
        imu_truth_sub = None if not imu_sub else unchecked(torch.Size([*n, len(imu_sub)]), {
            "gyro": torch.stack([gyro for gyro, _ in imu_sub], 1), "accel": torch.stack([accel for _, accel in imu_sub], 1)})
        new = unchecked(n, {
            "step": entry(state, "step") + 1,
            "body": unchecked(n, {**body._asdict(), "specific_force": specific_force}),  # initial()'s key order
            "wind": entry(state, "wind"),
            "sensors": entry(state, "sensors"),
            "control": unchecked(n, dict(ff=ff, cmd=cmd, **monitor)),  # initial()'s key order
            **({"base": entry(state, "base")} if "base" in state.keys() else {}),
            "nav": entry(state, "nav"),
        })
        new = self._observe_instant(params, new, first=False, imu_truth_sub=imu_truth_sub, wind_ne=wind_ne)
        new["finite"] = finite
        # contiguous leaves, as initial() returns: a compiled step is guarded on its input's strides
        return _contiguous(_sanitize(new, ~finite, self.physics_constants.zero, self._level))

    def _cos_tilt(self, state: TensorDict) -> Tensor:
        """``[N, 1]`` cosine of the tilt from vertical in the attitude the PD flies on: the body's,
        or the measured roll and pitch (Z-Y-X angles: the body z axis's vertical component is
        cos(roll) cos(pitch))."""
        if self.cfg.controller.feedback == "truth":
            return quat_to_rotmat(state["body", "quat"])[..., 2, 2:]
        attitude = state["sensors", MEAS_KEY, "attitude"]
        return torch.cos(attitude[..., :1]) * torch.cos(attitude[..., 1:2])

    # --- what the vehicle and the world look like at one instant --------------------------------

    def _observe_instant(
        self, params: TensorDict, state: TensorDict, first: bool, imu_truth_sub: TensorDict | None = None,
        wind_ne: Tensor | None = None,
    ) -> TensorDict:
        """``state`` completed with the wind, reference, sensors, navigation and the base
        controller's wrench at its current step (``imu_truth_sub``: the IMU's true inputs at its
        samples inside the step just flown; ``wind_ne``: the base law's wind estimate)."""
        body, step, sc = entry(state, "body"), entry(state, "step"), entry(params, "scenario")
        pos = entry(body, "pos")
        mean, total, wind_state = self.atmosphere.sample(entry(params, "wind"), entry(state, "wind"), pos,
                                                         self.control_dt)
        ref = self.trajectories.reference(entry(sc, "traj_id"), step, entry(params, "pattern_start"),
                                          entry(sc, "altitude_m"))
        rot = quat_to_rotmat(entry(body, "quat"))
        euler = euler_from_rotmat(rot)
        # what each instrument would read without noise or bias
        truth = unchecked(state.batch_size, dict(gps_pos=pos, gps_vel=entry(body, "vel"), baro_alt=pos[..., 2:],
                                                 attitude=euler, gyro=entry(body, "omega"),
                                                 accel=entry(body, "specific_force")))
        force = torch.ones_like(step, dtype=torch.bool).unsqueeze(-1) if first else None
        meas, sensor_state = self.sensors.measure(entry(params, "sensors"), entry(state, "sensors"), truth, step,
                                                  force=force, imu_truth_sub=imu_truth_sub)

        feedback = self.cfg.controller.feedback
        if feedback == "truth":
            nav = unchecked(state.batch_size, dict(pos=pos, vel=entry(body, "vel"),
                                                   baro_offset=torch.zeros_like(pos[..., 2:])))
            nav_rot, nav_omega = rot, entry(body, "omega")
        else:
            # the measured attitude as a rotation, once: the filter's prediction and the PD read it
            nav_rot = euler_to_rotmat(entry(meas, "attitude"))
            if feedback == "sensors" or first:
                nav = init_navigation(meas)
            else:
                nav = update_navigation(
                    entry(state, "nav"),
                    meas,
                    self.sensors.imu_mean(sensor_state, "accel"),
                    self.sensors.ticks(step, "gps_pos"),
                    self.sensors.ticks(step, "baro_alt"),
                    self.navigation,
                    self.control_dt,
                    rot=nav_rot,
                )
            nav_omega = entry(meas, "gyro")
        # the accelerometer as the law's feedback reads it: the true specific force with truth
        # feedback, or where the observer is given a perfect accelerometer
        perfect = feedback == "truth" or self.cfg.controller.observer_reads == "true_specific_force"
        specific_force = entry(body, "specific_force") if perfect else entry(meas, "accel")
        # the residual on the acceleration: the correction the step just set (zero at an episode's
        # start), from the reference heading's frame into the world's, for the wrench of the next step
        acc_correction = heading_to_world(entry(state, "control", "ff"), ref.yaw) if self.on_acceleration else None
        inputs = ControlInputs(pos=entry(nav, "pos"), vel=entry(nav, "vel"), rot=nav_rot, omega=nav_omega, ref=ref,
                               specific_force=specific_force, thrust_applied=entry(state, "control", "cmd")[..., :1],
                               wind_ne=wind_ne, armed=(step >= self.arm_step).unsqueeze(-1), first=first,
                               acc_correction=acc_correction)
        pd, base = self.controller(inputs, state.get("base", None))

        n = state.batch_size
        out = dict(state.items())
        out["wind"] = unchecked(n, {**dict(wind_state.items()), "mean": mean, "total": total})
        out["sensors"] = unchecked(n, {**dict(sensor_state.items()), MEAS_KEY: meas})
        out["nav"] = nav
        out["ref"] = unchecked(n, dict(pos=ref.pos, vel=ref.vel, acc=ref.acc, yaw=ref.yaw))
        out["control"] = unchecked(n, {**dict(state["control"].items()), "pd_wrench": pd.wrench, "tilt_cmd": pd.tilt_cmd,
                                         "tilt_saturated": pd.tilt_saturated})
        if base is not None:
            out["base"] = base
        return unchecked(n, out)


def _contiguous(td: TensorDict) -> TensorDict:
    """``td.apply(Tensor.contiguous)``, out of place, without ``apply``'s per-call machinery (a
    tenth of the eager step at one row)."""
    return TensorDict._new_unsafe(
        {k: _contiguous(v) if is_tensor_collection(v) else v.contiguous() for k, v in td.items()},
        batch_size=td.batch_size, device=td.device)


def _scatter_rows(full: TensorDict, rows: Tensor, part: TensorDict) -> TensorDict:
    """``full`` with its rows ``rows`` replaced by ``part``'s rows, out of place: the tensors of
    ``full`` may still be held by observations already returned."""
    return full.apply(lambda whole, new: whole.index_copy(0, rows, new), part)


def _sanitize(state: TensorDict, broken: Tensor, zero: Tensor, level: Tensor) -> TensorDict:
    """Rows whose physics went non-finite are parked at their reference, level (quaternion
    ``level``) and at rest, so nothing non-finite leaves the simulator (the task terminates them
    in the same step, on ``state["finite"]``). Branch-free: no host synchronisation in the step.
    ``zero``: a 0-dim zero of the state's dtype."""
    n = state.batch_size
    body = entry(state, "body")
    fixes = {"pos": entry(state, "ref", "pos"), "pos_carry": zero, "vel": zero, "quat": level, "omega": zero, "specific_force": zero}
    out = dict(state.items())
    out["body"] = unchecked(n, {k: torch.where(broken, fixes[k], v) if k in fixes else v for k, v in body.items()})
    # the measurements (a sub-tensordict of named entries), the wrenches and the wind are zeroed,
    # packed side by side: three ops, not three per entry
    zeroed = {"sensors": (MEAS_KEY,), "control": ("pd_wrench", "cmd", "ff"), "wind": ("total", "mean")}
    if "base" in state.keys():  # the base law's state restarts from zero in a parked row
        zeroed["base"] = tuple(state["base"].keys())
    groups = {group: dict(entry(state, group).items()) for group in zeroed}
    parts = [(group, key, name) for group, keys in zeroed.items() for key in keys
             for name in (groups[group][key].keys() if is_tensor_collection(groups[group][key]) else (None,))]
    leaves = [groups[group][key] if name is None else entry(groups[group][key], name) for group, key, name in parts]
    packed = torch.where(broken, zero, torch.cat(leaves, -1).nan_to_num())
    nested: dict[tuple[str, str], dict[str, Tensor]] = {}
    for (group, key, name), leaf in zip(parts, packed.split([leaf.shape[-1] for leaf in leaves], -1)):
        if name is None:
            groups[group][key] = leaf
        else:
            nested.setdefault((group, key), {})[name] = leaf
    for (group, key), entries in nested.items():
        groups[group][key] = unchecked(n, entries)
    out.update({group: unchecked(n, entries) for group, entries in groups.items()})
    return unchecked(n, out)
