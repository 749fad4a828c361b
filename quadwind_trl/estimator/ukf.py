"""A model-based wind estimator: an unscented Kalman filter on the airframe's own drag model.

It reads the same 10 Hz ``"horizontal"`` feature windows as the learned estimator and is a
:class:`~quadwind_trl.estimator.base.WindEstimator`, so ``WindEstimate`` runs it unchanged.
The formulation follows the accelerometer-drag wind filters of the literature (RotorPy's wind
EKF is a public one); ours differs where our airframe does (quadratic body drag, see below).

**State**: the horizontal wind at the vehicle ``w = (north, east)``, m/s; vertical wind is taken
as zero (mean vertical wind is zero in every regime; vertical gusts are left as model error).

**Process**: a random walk, ``w_{k+1} = w_k + n_k``, ``n_k ~ N(0, q dt I)``. The spectral density
``q = 2 sigma_u^2 V / L`` is the drive of the first-order Gauss-Markov process with the
turbulence's standard deviation ``sigma_u`` and the correlation time ``L / V`` with which a vehicle
at airspeed ``V`` crosses eddies of integral length ``L`` (Taylor's frozen field); as a walk it
lets the state follow the turbulent wind at that rate without assuming its mean.

**Measurement**: the accelerometer's body x and y channels. The rotors' thrust lies along body z
(``envs/vehicle.py``), so the specific force along body x and y is drag alone::

    f_b,i = -(k_i / m) v_b,i |v_b,i|,    v_b = R^T (v_ground - w),   i in {x, y}
    k_i = 1/2 rho C_dA_i

with ``R`` the measured attitude, ``v_ground`` the GNSS velocity. Using only these two channels
keeps the (commanded, not realised) thrust out of the model: body z mixes thrust and drag and
would need both. The features carry the heading only relative to the reference (``yaw_err``);
the absolute heading the sensors measured is recovered exactly from the world-frame ``aero_N``/
``aero_E`` channels, which are the body-frame force ``m f_b - u_T e_z`` turned by the measured
attitude (docs/features.md): the angle between that force levelled by roll and pitch and its
world-frame image is the measured yaw.

**Why unscented**: quadratic drag has zero slope at zero airspeed. An EKF started from zero wind
on a hovering vehicle linearises there, gets a zero Jacobian and never moves; the unscented
transform's sigma points (spread by the wide initial covariance) see the curvature and converge.

**Model error** (``UKFConfig.drag_scale``, ``mass_scale``): the filter's airframe is not the
simulated one. Only ``k / m`` enters, so the filter's drag-to-mass ratio is
``drag_scale / mass_scale`` times the truth, and in steady flight it infers each body-axis
airspeed ``sqrt(mass_scale / drag_scale)`` times the true one: the wind error is
``(1 - sqrt(mass_scale / drag_scale))`` times the air-relative velocity (9.1 % of it by default),
directed along it (``tests/test_ukf.py`` checks this closed form).

**Output**: each ``predict`` runs the filter over the window (stateless across calls: every window
starts from zero wind and ``initial_wind_std_m_s``) and returns the mean of the filtered wind over
the window's last ``average_last_s`` seconds. The target is the turbulence-free mean wind, while
the state follows the turbulent wind with a memory of a few tenths of a second; averaging its last
seconds removes part of the turbulence, and leaving out the window's start skips the convergence
from the wide prior. Only the ``"horizontal"`` schema carries the specific force and thrust.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

import torch
from torch import Tensor

from ..config import EnvConfig, SensorConfig, VehicleConfig, _check_range
from .features import _apply, make_extractor, rotation_from_euler

_SENSORS = SensorConfig()

#: the feature channels the filter reads (all in the "horizontal" schema)
UKF_INPUT_CHANNELS: tuple[str, ...] = (
    "vel_E", "vel_N", "vel_U", "roll", "pitch", "u_T", "sf_bx", "sf_by", "sf_bz", "aero_N", "aero_E",
)  # fmt: skip

# Julier's unscented transform for a 2-D Gaussian state: n + kappa = 3 matches the fourth moment
# of a Gaussian, and with n = 2 every weight is positive (a covariance from them stays positive)
_STATE_DIM = 2
_SIGMA_SCALE = 3.0  # n + kappa
_W0 = 1.0 / 3.0  # kappa / (n + kappa)
_WI = 1.0 / 6.0  # 1 / (2 (n + kappa))


@dataclass(frozen=True)
class UKFConfig:
    """Settings of :class:`WindUKF`, in SI units.

    Model error (the filter's airframe against the simulated one, ``VehicleConfig``):

    * ``drag_scale = 1.15``: the filter's ``C_dA`` is 15 % high. A real airframe's drag area is
      an estimate (a frontal area times a bluff-body ``C_d`` near 1, or one wind-tunnel or
      flight fit); it changes with payload, gimbal and battery placement, and the horizontal
      force of a real quadrotor also holds rotor H-force and induced drag, roughly linear in
      airspeed, which a quadratic ``C_dA`` fitted at one speed misses by tens of percent at
      others. 15 % is a modest share of that spread.
    * ``mass_scale = 0.95``: the filter's mass is 5 % low (130 g of the 2.59 kg): a battery or
      payload change that nobody re-weighed; survey quadrotors swap both between flights.

    Both errors push the same way (the filter over-predicts drag per unit airspeed, so it infers
    too little airspeed): the combined ``k / m`` error is +21 %, the wind error 9.1 % of the
    air-relative velocity. ``1.0``, ``1.0`` is the exact model.

    Noise levels default to the sensor suite's (``SensorConfig()``); ``heading_noise_rad`` adds
    the magnetometer yaw's white noise and bias in quadrature (the bias is constant over a window:
    the filter cannot average it away, so it is counted as noise). Process noise: see
    :attr:`process_psd_m2_s3`.
    """

    drag_scale: float = 1.15  # filter C_dA / true C_dA
    mass_scale: float = 0.95  # filter mass / true mass
    # the turbulence the random walk must follow: typical of the regime designs (intensity 0.15
    # at 10 m/s, the scenarios' default 150 m length scale, flown at the 10 m/s cruise speed)
    turbulence_std_m_s: float = 1.5
    turbulence_length_scale_m: float = 150.0
    airspeed_m_s: float = 10.0
    # wide enough that zero wind and the 20 m/s cap are both within two standard deviations
    initial_wind_std_m_s: float = 10.0
    accel_noise_m_s2: float = _SENSORS.accel.noise_std
    gnss_velocity_noise_m_s: float = _SENSORS.gps_vel.noise_std
    heading_noise_rad: float = math.hypot(_SENSORS.attitude_yaw.noise_std, _SENSORS.attitude_yaw.bias_std)
    average_last_s: float = 3.0  # 0: the filter's final estimate
    window: int = 60  # samples (10 Hz): the learned estimator's 6 s

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        ranges = {
            "drag_scale": (0.25, 4.0),
            "mass_scale": (0.25, 4.0),
            "turbulence_std_m_s": (0.0, 10.0),
            "turbulence_length_scale_m": (1.0, 5000.0),
            "airspeed_m_s": (0.1, 50.0),
            "initial_wind_std_m_s": (0.1, 100.0),
            "accel_noise_m_s2": (1e-4, 10.0),  # > 0: the innovation covariance must be invertible
            "gnss_velocity_noise_m_s": (0.0, 10.0),
            "heading_noise_rad": (0.0, 0.5),
            "average_last_s": (0.0, 600.0),
            "window": (1, 3000),
        }
        for f in fields(self):
            _check_range("UKFConfig", f.name, getattr(self, f.name), *ranges[f.name])
        if not isinstance(self.window, int):
            raise ValueError(f"UKFConfig.window={self.window!r}; allowed: an integer number of samples in [1, 3000]")

    @property
    def process_psd_m2_s3(self) -> float:
        """Random-walk spectral density ``q = 2 sigma_u^2 V / L`` (m^2/s^3; 0.3 by default)."""
        return 2.0 * self.turbulence_std_m_s**2 * self.airspeed_m_s / self.turbulence_length_scale_m


def heading_from_aero(roll: Tensor, pitch: Tensor, sf_b: tuple[Tensor, Tensor, Tensor], u_t: Tensor,
                      aero_e: Tensor, aero_n: Tensor, feature_mass_kg: float) -> tuple[Tensor, Tensor]:
    """``(cos, sin)`` of the measured yaw, recovered from the features: ``aero_(E, N)`` is
    ``Rz(yaw)`` applied to the levelled body force ``[Ry Rx (m f_b - u_T e_z)]_xy``.

    ``feature_mass_kg`` is the mass the features were built with (the extractor's). Where the
    force vanishes (no drag, exact thrust) the heading is undefined and ``(1, 0)`` is returned."""
    level = rotation_from_euler(roll, pitch, torch.zeros_like(roll))
    q = _apply(level, (feature_mass_kg * sf_b[0], feature_mass_kg * sf_b[1], feature_mass_kg * sf_b[2] - u_t))
    dot = q[0] * aero_e + q[1] * aero_n
    cross = q[0] * aero_n - q[1] * aero_e
    norm = torch.sqrt(dot * dot + cross * cross)
    defined = norm > 0
    safe = torch.where(defined, norm, 1.0)
    return torch.where(defined, dot / safe, 1.0), torch.where(defined, cross / safe, 0.0)


def body_air_velocity(wind_ne: Tensor, vel_enu: tuple[Tensor, Tensor, Tensor], level: tuple, cos_yaw: Tensor,
                      sin_yaw: Tensor) -> tuple[Tensor, Tensor, tuple[Tensor, Tensor]]:
    """Body x and y air-relative velocity ``[B, S]`` for wind hypotheses ``wind_ne`` ``[B, S, 2]``;
    also the level-frame horizontal air velocity (x, y), which the heading noise acts on.

    ``vel_enu``, ``level`` (``Ry Rx`` rows), ``cos_yaw``, ``sin_yaw``: ``[B, 1]`` tensors."""
    air_e = vel_enu[0] - wind_ne[..., 1]
    air_n = vel_enu[1] - wind_ne[..., 0]
    # Rz(yaw)^T, then (Ry Rx)^T: body_i = sum_j level[j][i] l_j
    lx = cos_yaw * air_e + sin_yaw * air_n
    ly = -sin_yaw * air_e + cos_yaw * air_n
    lz = vel_enu[2]
    bx = level[0][0] * lx + level[1][0] * ly + level[2][0] * lz
    by = level[0][1] * lx + level[1][1] * ly + level[2][1] * lz
    return bx, by, (lx, ly)


def _cholesky_2x2(p: Tensor) -> Tensor:
    """Lower Cholesky factor ``[B, 2, 2]`` of symmetric ``p`` (closed form, floored: float32
    round-off in one row can never make a solver fail the whole batch)."""
    l11 = p[:, 0, 0].clamp_min(1e-12).sqrt()
    l21 = p[:, 1, 0] / l11
    l22 = (p[:, 1, 1] - l21 * l21).clamp_min(1e-12).sqrt()
    zero = torch.zeros_like(l11)
    return torch.stack((torch.stack((l11, zero), -1), torch.stack((l21, l22), -1)), -2)


def _inverse_2x2(s: Tensor) -> Tensor:
    det = s[:, 0, 0] * s[:, 1, 1] - s[:, 0, 1] * s[:, 1, 0]
    adj = torch.stack((torch.stack((s[:, 1, 1], -s[:, 0, 1]), -1), torch.stack((-s[:, 1, 0], s[:, 0, 0]), -1)), -2)
    return adj / det[:, None, None]


def ukf_wind_track(windows: Tensor, channels: tuple[str, ...], cfg: UKFConfig, vehicle: VehicleConfig,
                   feature_mass_kg: float, dt_s: float) -> tuple[Tensor, Tensor]:
    """Run the filter over raw feature windows ``[B, T, C]`` (``channels`` names C): the filtered
    wind ``[B, T, 2]`` (north, east, m/s) after each sample and its covariance ``[B, T, 2, 2]``.

    ``vehicle`` is the true airframe (the filter's is it scaled by ``cfg``); ``feature_mass_kg``
    the mass the features were built with (it only undoes the ``aero`` channels' definition)."""
    # time-major [T, B, 1] inputs: sample t broadcasts over the sigma points
    col = {name: windows[..., channels.index(name)].T.unsqueeze(-1) for name in UKF_INPUT_CHANNELS}
    t_len, b = col["roll"].shape[:2]
    roll, pitch = col["roll"], col["pitch"]
    sf_b = (col["sf_bx"], col["sf_by"], col["sf_bz"])
    cos_yaw, sin_yaw = heading_from_aero(roll, pitch, sf_b, col["u_T"], col["aero_E"], col["aero_N"], feature_mass_kg)
    level = rotation_from_euler(roll, pitch, torch.zeros_like(roll))
    # the filter's drag-to-mass ratio per body axis (x and y share C_dA), 1/m
    k_over_m = (0.5 * vehicle.air_density_kg_m3 * vehicle.drag_area_xy_m2 * cfg.drag_scale
                / (vehicle.mass_kg * cfg.mass_scale))
    q_step = cfg.process_psd_m2_s3 * dt_s
    var_a = cfg.accel_noise_m_s2**2
    var_v = cfg.gnss_velocity_noise_m_s**2
    var_yaw = cfg.heading_noise_rad**2

    x = windows.new_zeros(b, _STATE_DIM)
    eye = torch.eye(_STATE_DIM, dtype=windows.dtype, device=windows.device)
    p = eye.expand(b, -1, -1) * cfg.initial_wind_std_m_s**2
    w_sigma = windows.new_tensor([_W0] + [_WI] * (2 * _STATE_DIM))  # [S]
    track, covs = [], []
    for t in range(t_len):
        p = p + q_step * eye  # predict: the walk (the first sample is predicted from the prior too)
        vel = (col["vel_E"][t], col["vel_N"][t], col["vel_U"][t])
        lev = tuple(tuple(e[t] for e in row) for row in level)
        spread = math.sqrt(_SIGMA_SCALE) * _cholesky_2x2(p)  # columns: the sigma offsets
        offsets = torch.cat((x.new_zeros(b, 1, _STATE_DIM), spread.transpose(1, 2), -spread.transpose(1, 2)), 1)
        points = x[:, None, :] + offsets  # [B, S, 2]
        bx, by, (lx, ly) = body_air_velocity(points, vel, lev, cos_yaw[t], sin_yaw[t])
        z_pts = torch.stack((-k_over_m * bx * bx.abs(), -k_over_m * by * by.abs()), -1)  # [B, S, 2]
        z_mean = (w_sigma[:, None] * z_pts).sum(1)
        dz = z_pts - z_mean[:, None, :]
        dx = points - x[:, None, :]
        # measurement noise at the prior mean (sigma point 0): the accelerometer, plus the GNSS
        # velocity and heading errors carried through the drag slope 2 (k/m) |v_b|
        slope2 = (2.0 * k_over_m) ** 2
        r_x = var_a + slope2 * bx[:, 0] ** 2 * (var_v + var_yaw * ly[:, 0] ** 2)
        r_y = var_a + slope2 * by[:, 0] ** 2 * (var_v + var_yaw * lx[:, 0] ** 2)
        s = torch.einsum("s,bsi,bsj->bij", w_sigma, dz, dz) + torch.diag_embed(torch.stack((r_x, r_y), -1))
        c = torch.einsum("s,bsi,bsj->bij", w_sigma, dx, dz)
        gain = c @ _inverse_2x2(s)
        z = torch.cat((col["sf_bx"][t], col["sf_by"][t]), -1)
        # the innovation is taken against the measurement predicted at the mean (sigma point 0),
        # not the sigma points' weighted mean: that mean of a quadratic carries + k P, which in
        # steady flight settles as a wind bias of P / (2 |v_b|) (0.03 m/s at 3 m/s airspeed,
        # growing as the airspeed falls). The covariances still come from the sigma points.
        x = x + (gain @ (z - z_pts[:, 0])[..., None])[..., 0]
        p = p - gain @ s @ gain.transpose(1, 2)
        p = 0.5 * (p + p.transpose(1, 2))
        track.append(x)
        covs.append(p)
    return torch.stack(track, 1), torch.stack(covs, 1)


class WindUKF:
    """The unscented Kalman filter as a :class:`~quadwind_trl.estimator.base.WindEstimator`
    (schema ``"horizontal"``); ``config`` is the env's (the features' mass and log rate, and the
    true airframe the filter's model error is stated against)."""

    schema = "horizontal"

    def __init__(self, cfg: UKFConfig | None = None, config: EnvConfig | None = None):
        self.cfg = cfg or UKFConfig()
        env_cfg = config or EnvConfig()
        extractor = make_extractor(self.schema, env_cfg)
        self.channels: tuple[str, ...] = extractor.channels
        self.vehicle = env_cfg.vehicle
        self.feature_mass_kg = extractor.mass_kg
        self.dt_s = extractor.log_dt_s

    @property
    def window(self) -> int:
        return self.cfg.window

    def track(self, windows: Tensor) -> tuple[Tensor, Tensor]:
        """The filtered wind ``[B, T, 2]`` and covariance ``[B, T, 2, 2]`` along each window."""
        if windows.ndim != 3 or windows.shape[-1] != len(self.channels):
            raise ValueError(f"WindUKF: windows of shape {tuple(windows.shape)}; expected [B, T, {len(self.channels)}]")
        return ukf_wind_track(windows, self.channels, self.cfg, self.vehicle, self.feature_mass_kg, self.dt_s)

    @torch.no_grad()
    def predict(self, windows: Tensor) -> Tensor:
        """Raw feature windows ``[B, T, C]`` -> mean wind ``[B, 2]`` (north, east), m/s: the mean of
        the filtered wind over the last ``average_last_s`` (at least the final sample)."""
        wind, _ = self.track(windows)
        last = min(max(1, round(self.cfg.average_last_s / self.dt_s)), wind.shape[1])
        return wind[:, -last:].mean(1)

    def to(self, device: torch.device | str) -> "WindUKF":
        return self  # no tensors held: everything follows the windows' device
