"""The flight envelope: the largest steady horizontal airspeed the vehicle can hold in level flight.

Pure tensor functions over :class:`~quadwind_trl.envs.vehicle.VehicleParams` (the simulator's own
drag, rotor model and limits; nothing re-typed). The vehicle flies at airspeed ``V`` (its velocity
relative to the air) along a body axis, pitched by ``tilt`` into the relative wind; in steady level
flight the rotor thrust ``T`` along body ``+z`` balances the body-axis quadratic drag
(:func:`~quadwind_trl.envs.vehicle.drag_force_body`) and the weight::

    T sin(tilt) = D_along(V, tilt)          (horizontal: thrust against drag)
    T cos(tilt) = m g - D_up(V, tilt)       (altitude hold; D_up is the drag's vertical part)

so ``(m g - D_up) tan(tilt) = D_along``, both drag terms quadratic in ``V``. Two limits bound ``V``:

* **tilt**: the PD's commanded-tilt limit (``ControllerConfig.max_tilt_deg``) caps ``tilt``: at
  the limit the balance is a quadratic in ``V``, solved in closed form;
* **thrust**: the rotors must deliver ``T``. The PD allocates with the static law, so the most it
  commands is the collective limit (or the rotors' speed limit, whichever is lower), and each
  rotor then delivers that times the rotor model's :func:`~quadwind_trl.envs.vehicle.rotor_thrust_ratio`
  at the trimmed airflow through its disc (with ``rotor_aero="static"`` the ratio is 1). Found on
  a grid of airspeeds, the tilt free.

The heading is along a body axis, where the per-axis drag is largest (the airspeed held along the
diagonal is higher); the ``omega x r`` hub velocity, turns and climbs are not part of the balance.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ..config import GRAVITY_M_S2, ControllerConfig, VehicleConfig
from .rotations import rotate, rotate_inverse
from .vehicle import VehicleParams, drag_force_body, rotor_thrust_ratio

_TRIM_BISECTIONS = 60  # halves an 89 deg bracket to ~1e-16 rad
_MAX_TRIM_TILT_RAD = math.radians(89.0)
_SCAN_STEP_M_S = 0.01  # resolution of the thrust-limited airspeed
_SCAN_MAX_M_S = 80.0  # no rotorcraft of this size holds more


def pitch_rotation(tilt: Tensor) -> Tensor:
    """``[..., 3, 3]`` body-to-world rotation of a vehicle heading along world +x (its body x),
    pitched nose-down by ``tilt`` (rad): the thrust axis leans towards +x."""
    c, s = torch.cos(tilt), torch.sin(tilt)
    zero, one = torch.zeros_like(tilt), torch.ones_like(tilt)
    rows = ((c, zero, s), (zero, one, zero), (-s, zero, c))
    return torch.stack([torch.stack(row, -1) for row in rows], -2)


def air_velocity_body(airspeed: Tensor, tilt: Tensor) -> Tensor:
    """``[..., 3]`` body-frame velocity relative to the air of a vehicle flying at ``airspeed``
    along world +x, pitched by ``tilt``: ``V cos(tilt)`` along body x, ``V sin(tilt)`` along the
    rotor axis (air flowing down through the discs, as in a climb)."""
    air_world = torch.stack((airspeed, torch.zeros_like(airspeed), torch.zeros_like(airspeed)), -1)
    return rotate_inverse(pitch_rotation(tilt), air_world)


def drag_world(airspeed: Tensor, tilt: Tensor, p: VehicleParams) -> tuple[Tensor, Tensor]:
    """The drag's magnitude against the motion (``D_along``, N) and its upward part (``D_up``, N)."""
    force = rotate(pitch_rotation(tilt), drag_force_body(air_velocity_body(airspeed, tilt), p.drag_half_rho_cda))
    return -force[..., 0], force[..., 2]


def trim_tilt(airspeed: Tensor, p: VehicleParams) -> Tensor:
    """The pitch (rad) of steady level flight at ``airspeed``, no tilt limit: the root of
    ``(m g - D_up) tan(tilt) - D_along`` by bisection (negative at zero tilt, growing without bound
    towards 90 deg)."""
    weight = p.mass * GRAVITY_M_S2
    low, high = torch.zeros_like(airspeed), torch.full_like(airspeed, _MAX_TRIM_TILT_RAD)
    for _ in range(_TRIM_BISECTIONS):
        mid = 0.5 * (low + high)
        along, up = drag_world(airspeed, mid, p)
        short = (weight - up) * torch.tan(mid) < along
        low, high = torch.where(short, mid, low), torch.where(short, high, mid)
    return 0.5 * (low + high)


def trim_thrust(airspeed: Tensor, tilt: Tensor, p: VehicleParams) -> Tensor:
    """The rotor thrust (N, delivered) that holds altitude at ``airspeed`` and ``tilt``."""
    _, up = drag_world(airspeed, tilt, p)
    return (p.mass * GRAVITY_M_S2 - up) / torch.cos(tilt)


def max_commanded_thrust(p: VehicleParams) -> float:
    """The largest collective (N, in the static law the PD allocates with): the collective limit,
    or four rotors at their speed limit if that is lower."""
    return min(p.collective_max, 4.0 * p.rotor_thrust_max)


def available_thrust(airspeed: Tensor, tilt: Tensor, p: VehicleParams) -> Tensor:
    """The thrust (N) the rotors deliver at the largest command, in the trimmed airflow."""
    command = max_commanded_thrust(p)
    if p.rotor is None:
        return torch.full_like(airspeed, command)
    speed = torch.full((*airspeed.shape, 4), math.sqrt(command / 4.0 / p.thrust_coeff), dtype=airspeed.dtype, device=airspeed.device)
    ratio = rotor_thrust_ratio(air_velocity_body(airspeed, tilt), speed, p.rotor)
    return command * ratio.mean(-1)


def tilt_limited_airspeed(p: VehicleParams, max_tilt_rad: float) -> float:
    """Airspeed (m/s) at which level flight needs exactly the tilt limit: with ``D = V^2 d(tilt)``,
    ``V^2 = m g tan(tilt) / (d_along + d_up tan(tilt))``."""
    tilt = torch.tensor(max_tilt_rad, dtype=torch.float64)
    along, up = drag_world(torch.ones_like(tilt), tilt, p)
    return math.sqrt(p.mass * GRAVITY_M_S2 * math.tan(max_tilt_rad) / (along + up * math.tan(max_tilt_rad)).item())


def thrust_limited_airspeed(p: VehicleParams) -> float:
    """The lowest airspeed (m/s) at which trimmed level flight needs more thrust than the rotors
    deliver (the tilt unlimited); ``inf`` if none up to 80 m/s."""
    airspeed = torch.arange(0.0, _SCAN_MAX_M_S + _SCAN_STEP_M_S, _SCAN_STEP_M_S, dtype=torch.float64)
    tilt = trim_tilt(airspeed, p)
    short = trim_thrust(airspeed, tilt, p) > available_thrust(airspeed, tilt, p)
    return round(airspeed[short.nonzero()[0, 0]].item(), 2) if short.any() else math.inf


@dataclass(frozen=True)
class FlightEnvelope:
    """The largest steady level-flight airspeed (m/s), by limit."""

    tilt_limited_m_s: float  # the commanded-tilt limit against drag, thrust unlimited
    thrust_limited_m_s: float  # the rotors' thrust (at the collective or rotor-speed limit), tilt unlimited
    max_tilt_deg: float
    max_thrust_n: float  # the largest commanded collective (static law)

    @property
    def airspeed_m_s(self) -> float:
        return min(self.tilt_limited_m_s, self.thrust_limited_m_s)

    @property
    def binding(self) -> str:
        return "tilt" if self.tilt_limited_m_s <= self.thrust_limited_m_s else "thrust"


def flight_envelope(vehicle: VehicleConfig | None = None, controller: ControllerConfig | None = None) -> FlightEnvelope:
    """The envelope of ``vehicle`` flown by the PD cascade ``controller`` (defaults: the project's)."""
    vehicle, controller = vehicle or VehicleConfig(), controller or ControllerConfig()
    controller.validate()
    p = VehicleParams.from_config(vehicle)
    return FlightEnvelope(
        tilt_limited_m_s=tilt_limited_airspeed(p, math.radians(controller.max_tilt_deg)),
        thrust_limited_m_s=thrust_limited_airspeed(p),
        max_tilt_deg=controller.max_tilt_deg,
        max_thrust_n=max_commanded_thrust(p),
    )
