"""Wind at the vehicle: a turbulence-free mean profile plus spectral von Karman turbulence.

Mean profile (paper Eq. 1) and veer::

    U(z)     = U_ref * (max(z, z_ref) / z_ref) ** alpha              (capped at max_horizontal_wind)
    from(z)  = from_0 + veer * (max(z, z_ref) - z_ref) / 100 m       (meteorological "from", CW from N)

so the wind blows towards ``from + 180 deg``; in ENU its components are
``(-U sin(from), -U cos(from), 0)`` (east, north, up).

Turbulence is a sum of Fourier modes evaluated directly at the vehicle position (no grid):
``u(x) = sum_m a_m d_m cos(k_m . x + phi_m)``, each mode velocity ``d_m`` perpendicular to its
wavevector ``k_m`` (divergence free), amplitudes from the von Karman energy spectrum. This is the
TurboGenPY spectral-mode construction without the cube: no grid cutoff, no interpolation, and
memory O(N x modes). The field is frozen and advected with the local mean wind (Taylor's
hypothesis): it is evaluated at ``x - xi`` where ``xi`` integrates the mean wind along the
vehicle's altitude history (integrating, rather than using ``U(z) t``, keeps a climbing vehicle
from sweeping through the field at a spurious speed).

Batched cheaply: all sub-envs share one *skeleton* of unit wavevector directions and mode
velocity directions; each sub-env gets its own uniformly random 3-D rotation of the skeleton,
its own phases and its own length scale, so one episode's field is a function of its own seed
only, and the evaluation is two small matmuls. Averaged over rotations the skeleton is exactly
isotropic, so the realised statistics pooled over episodes are the requested ones.

Layouts (``TurbulenceConfig.layout``):

* ``"full"``: dimensionless wavenumbers ``kappa = k L`` log-spaced over ``kappa_range``
  (default 2 pi / 60 to 800, i.e. k up to 2-16 rad/m for L = 400-50 m), amplitudes normalised
  so each component has exactly unit variance before scaling (the 1.4 % of variance above the
  top mode is folded into the resolved modes).
* ``"paper_cube"``: the paper's cube, physical k linear from 2 pi / 1200 m to the 64-point
  grid's Nyquist pi / 18.75 m, amplitudes straight from the spectrum: it realises only the
  variance its k range holds (60-80 %).

Intensity and anisotropy: ``sigma_u = I U(z) (max(z, z_ref)/z_ref)^(-e)`` with a mild
``e = TurbulenceConfig.intensity_altitude_exponent``; ``sigma_v``, ``sigma_w`` follow from the
stability regime's ratios, applied in the frame of the local mean wind (longitudinal, lateral,
vertical).
"""
from __future__ import annotations

import math

import torch
from torch import Tensor

from ..config import TurbulenceConfig, WindProfileConfig
from .counter_rng import hash_normal, hash_uniform
from .rotations import quat_to_rotmat
from .trajectories import FIXED_ALTITUDE, TRAJECTORIES

VON_KARMAN_KE_L = 0.746834  # k_e L: peak wavenumber of the von Karman energy spectrum
VON_KARMAN_NORM = 1.452762  # makes the energy spectrum integrate to 3/2 sigma^2

_STREAM_ROTATION = 101
_STREAM_PHASE = 102


def von_karman_energy(k: Tensor, length_scale: Tensor | float, sigma: Tensor | float = 1.0) -> Tensor:
    """Energy spectrum E(k) (m^3/s^2) whose integral over k is ``1.5 sigma^2``."""
    k_e = VON_KARMAN_KE_L / length_scale
    x = k / k_e
    x2 = x * x
    # exp/log rather than ``**``: see Atmosphere._profile (batch-independent rounding)
    return VON_KARMAN_NORM * sigma**2 / k_e * (x2 * x2) * torch.exp(-(17.0 / 6.0) * torch.log(1.0 + x2))


def von_karman_longitudinal(kappa: Tensor, length_scale: float, sigma: float = 1.0) -> Tensor:
    """One-sided 1-D longitudinal spectrum per rad/m: sigma^2 (2L/pi) / (1 + (1.339 L k)^2)^(5/6)."""
    return sigma**2 * (2 * length_scale / math.pi) / (1 + (1.339 * length_scale * kappa) ** 2) ** (5.0 / 6.0)


def _mode_widths(k: Tensor, log_spaced: bool) -> Tensor:
    if log_spaced:
        logk = k.log()
        mid = 0.5 * (logk[1:] + logk[:-1])
        edges = torch.cat((2 * logk[:1] - mid[:1], mid, 2 * logk[-1:] - mid[-1:])).exp()
    else:
        mid = 0.5 * (k[1:] + k[:-1])
        edges = torch.cat((2 * k[:1] - mid[:1], mid, 2 * k[-1:] - mid[-1:]))
    return edges[1:] - edges[:-1]


class Atmosphere:
    """Mean profile plus turbulence for a batch of episodes (pure methods over state dicts)."""

    def __init__(self, wind: WindProfileConfig, turbulence: TurbulenceConfig, device: torch.device | str | None = None):
        turbulence.validate()
        self.wind = wind
        self.turbulence = turbulence
        self.device = torch.device(device) if device is not None else torch.device("cpu")
        m = turbulence.num_modes
        gen = torch.Generator().manual_seed(turbulence.skeleton_seed)
        direction = torch.randn(m, 3, generator=gen, dtype=torch.float64)
        direction = direction / direction.norm(dim=-1, keepdim=True)
        # a random unit vector perpendicular to each wavevector direction
        helper = torch.randn(m, 3, generator=gen, dtype=torch.float64)
        velocity_dir = torch.linalg.cross(direction, helper)
        velocity_dir = velocity_dir / velocity_dir.norm(dim=-1, keepdim=True)

        if turbulence.layout == "full":
            lo, hi = turbulence.kappa_range
            kappa = torch.logspace(math.log10(lo), math.log10(hi), m, dtype=torch.float64)
            energy = von_karman_energy(kappa, 1.0) * _mode_widths(kappa, log_spaced=True)
            amp = 2.0 * energy.sqrt()
            amp = amp * math.sqrt(3.0 / (0.5 * (amp**2).sum()))  # unit variance per component
            self.shared_amplitude: Tensor | None = amp.to(torch.float32).to(self.device)
        else:
            spacing = turbulence.cube_size_m / turbulence.cube_points
            kappa = torch.linspace(2 * math.pi / turbulence.cube_size_m, math.pi / spacing, m, dtype=torch.float64)
            self.shared_amplitude = None
            self._paper_widths = _mode_widths(kappa, log_spaced=False).to(torch.float32).to(self.device)
        self.wavenumber = kappa.to(torch.float32).to(self.device)  # kappa (full) or k in rad/m (cube)
        self.wave_dir = direction.to(torch.float32).to(self.device)  # [M, 3]
        self.velocity_dir = velocity_dir.to(torch.float32).to(self.device)  # [M, 3]
        # kappa_m d_m: dimensionless (full; scaled by 1 / L per episode) or in rad/m (cube)
        self._wavevector = (kappa.unsqueeze(-1) * direction).to(torch.float32).to(self.device)  # [M, 3]
        self._velocity_dir_t = self.velocity_dir.T.contiguous()  # [3, M]
        self.stability_ratios = torch.tensor(
            [(1.0, v, w) for v, w in turbulence.stability_ratios], dtype=torch.float32, device=self.device
        )
        self._fixed_altitude = torch.tensor([name in FIXED_ALTITUDE for name in TRAJECTORIES], device=self.device)

    # --- per-episode parameters ---------------------------------------------------------------

    def init_state(self, scenario: dict[str, Tensor]) -> dict[str, Tensor]:
        """Per-episode wind parameters and the advection state, from scenario fields ``[N]``."""
        seed = scenario["turb_seed"]
        n = seed.shape[0]
        q = hash_normal(seed, 0, _STREAM_ROTATION, 4)
        qw, qx, qy, qz = q.unbind(-1)
        q = q / torch.sqrt(qw * qw + qx * qx + qy * qy + qz * qz).unsqueeze(-1)
        rotation = quat_to_rotmat(q)  # uniform on SO(3)
        base_from = torch.deg2rad(scenario["wind_dir_deg"].to(torch.float32))
        veer = torch.deg2rad(scenario["veer_deg_per_100m"].to(torch.float32)) / 100.0
        # The anisotropy frame is the mean-wind frame (along, across, up) at the altitude the
        # flight spends its time at: a horizontal pattern's altitude, the middle of a vertical
        # pattern's climb (a vertical design carries its top altitude). It is fixed per episode:
        # a frame that followed the veer with height would make the coordinate map below depend
        # on z, whose derivative grows with the distance from the field's origin (km after the
        # advection) and would destroy the divergence-freeness (docs/atmosphere.md, 2.3).
        altitude = scenario["altitude_m"].to(torch.float32)
        anchor = torch.where(self._fixed_altitude[scenario["traj_id"]], altitude, 0.5 * altitude)
        z_ref = self.wind.reference_height_m
        anchor_from = base_from + veer * (anchor.clamp_min(z_ref) - z_ref)
        frame = _rot_z(-torch.sin(anchor_from), -torch.cos(anchor_from))  # columns: along, across, up
        ratios = self.stability_ratios[scenario["stability"]]  # (1, sigma_v / sigma_u, sigma_w / sigma_u)
        # gust(x) = sigma_u F D R v(R^T D^-1 F^T x): the coordinate map is the inverse transpose
        # of the velocity map, so every mode's stretched wavevector stays perpendicular to its
        # stretched velocity and the applied field is exactly divergence-free (docs/atmosphere.md)
        field_out = _matmul3(frame * ratios.unsqueeze(-2), rotation)  # F D R
        field_in = _matmul3(rotation.transpose(-1, -2), frame.transpose(-1, -2) / ratios.unsqueeze(-1))  # R^T D^-1 F^T
        length = scenario["turb_length_scale_m"].to(torch.float32)
        if self.shared_amplitude is not None:
            amplitude = self.shared_amplitude.expand(n, -1)
            k_scale = 1.0 / length
        else:
            energy = von_karman_energy(self.wavenumber, length.unsqueeze(-1))
            amplitude = 2.0 * (energy * self._paper_widths).sqrt()
            k_scale = torch.ones_like(length)
        return {
            "wind_speed_ref": scenario["wind_speed_ref_m_s"].to(torch.float32),
            "wind_from0": base_from,
            "shear_alpha": scenario["shear_alpha"].to(torch.float32),
            "veer_rad_per_m": veer,
            "intensity": scenario["turb_intensity"].to(torch.float32),
            "ratios": ratios,
            "field_in": field_in,
            "field_out": field_out,
            "phase": 2 * math.pi * hash_uniform(seed, 0, _STREAM_PHASE, self.turbulence.num_modes),
            "amplitude": amplitude.contiguous(),
            "k_scale": k_scale.unsqueeze(-1),
            "air_offset": torch.zeros(n, 3, device=seed.device),
        }

    # --- evaluation ---------------------------------------------------------------------------

    def _profile(self, state: dict[str, Tensor], z: Tensor) -> tuple[Tensor, Tensor]:
        """Capped mean speed and the "from" direction (rad) at altitudes ``z``."""
        z_ref = self.wind.reference_height_m
        zc = z.clamp_min(z_ref)
        # (zc / z_ref) ** alpha written as exp(alpha log(.)): torch's CPU pow (and atan2) round
        # differently in the vectorised body and the scalar tail of a kernel, which made a row's
        # wind depend on the batch size; exp and log do not (tests/test_atmosphere.py)
        speed = state["wind_speed_ref"] * torch.exp(state["shear_alpha"] * torch.log(zc / z_ref))
        speed = speed.clamp_max(self.wind.max_horizontal_wind_m_s)
        wind_from = state["wind_from0"] + state["veer_rad_per_m"] * (zc - z_ref)
        return speed, wind_from

    def mean_wind(self, state: dict[str, Tensor], z: Tensor) -> Tensor:
        """``[N, 3]`` turbulence-free mean wind (ENU) at altitudes ``z`` ``[N]``."""
        speed, wind_from = self._profile(state, z)
        return torch.stack((-speed * torch.sin(wind_from), -speed * torch.cos(wind_from), torch.zeros_like(speed)), -1)

    def unit_gust(self, state: dict[str, Tensor], field_pos: Tensor) -> Tensor:
        """The episode's anisotropic gust (ENU) per unit sigma_u, at positions in the frozen field's frame.

        ``F D R v(R^T D^-1 F^T x)``: ``v`` the unit-variance mode sum in the skeleton frame, ``R``
        the episode's rotation, ``D = diag(1, sigma_v / sigma_u, sigma_w / sigma_u)`` its
        regime's ratios in the anchor frame ``F`` (``init_state``). ``field_pos`` is ``[N, 3]``
        (or ``[..., N, 3]``: several points per episode). Written with elementwise operations in
        a fixed order and one sum over each row's contiguous modes, never a matmul: BLAS picks
        kernels (and summation orders) by the batch size, which made a row's wind depend on how
        many rows shared its batch (tests/test_atmosphere.py).
        """
        m_in, m_out = state["field_in"], state["field_out"]
        x, y, z = field_pos[..., 0], field_pos[..., 1], field_pos[..., 2]
        k_scale = state["k_scale"]
        theta = state["phase"]
        for c in range(3):  # theta = phase + sum_c (M_in x)_c k_scale kappa_m d_mc
            local = x * m_in[..., c, 0] + y * m_in[..., c, 1] + z * m_in[..., c, 2]
            theta = theta + (local.unsqueeze(-1) * k_scale) * self._wavevector[:, c]
        modes = torch.cos(theta) * state["amplitude"]
        bx, by, bz = ((modes * self._velocity_dir_t[c]).sum(-1) for c in range(3))  # skeleton frame
        return torch.stack([m_out[..., r, 0] * bx + m_out[..., r, 1] * by + m_out[..., r, 2] * bz for r in range(3)], -1)

    def turbulence_sigma(self, state: dict[str, Tensor], mean: Tensor, z: Tensor) -> Tensor:
        """``[N, 3]`` requested standard deviations at altitude ``z``, in the episode's anchor frame.

        (along, across, up) of the mean wind at the anchor altitude (``init_state``); the gust
        is ``sigma_u`` times ``unit_gust``, whose ensemble variances are ``(1, r_v^2, r_w^2)``.
        """
        z_ref = self.wind.reference_height_m
        speed = torch.sqrt(mean[..., 0] * mean[..., 0] + mean[..., 1] * mean[..., 1])
        decay = torch.exp(-self.turbulence.intensity_altitude_exponent * torch.log(z.clamp_min(z_ref) / z_ref))
        return (state["intensity"] * speed * decay).unsqueeze(-1) * state["ratios"]

    def sample(
        self, state: dict[str, Tensor], pos: Tensor, dt: float
    ) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """Mean and total wind ``[N, 3]`` at ``pos``; the state advected by ``dt`` seconds.

        The returned wind applies over the coming ``dt`` (the simulator holds it over the
        control step's physics substeps).
        """
        z = pos[..., 2]
        mean = self.mean_wind(state, z)
        total = mean
        if self.turbulence.enabled:
            sigma_u = self.turbulence_sigma(state, mean, z)[..., :1]
            total = mean + sigma_u * self.unit_gust(state, pos - state["air_offset"])
        if self.wind.cap_applies_to == "total":
            total = _cap_horizontal(total, self.wind.max_horizontal_wind_m_s)
        state = dict(state, air_offset=state["air_offset"] + dt * mean)
        return mean, total, state


def _cap_horizontal(wind: Tensor, cap: float) -> Tensor:
    horiz = wind[..., :2]
    norm = torch.sqrt(horiz[..., 0:1] * horiz[..., 0:1] + horiz[..., 1:2] * horiz[..., 1:2])
    scale = torch.where(norm > cap, cap / norm.clamp_min(1e-9), 1.0)
    return torch.cat((horiz * scale, wind[..., 2:]), -1)


def _rot_z(c: Tensor, s: Tensor) -> Tensor:
    """Rotation about z by the angle whose cosine and sine are ``c`` and ``s``."""
    zero, one = torch.zeros_like(c), torch.ones_like(c)
    return torch.stack((c, -s, zero, s, c, zero, zero, zero, one), -1).unflatten(-1, (3, 3))


def _matmul3(a: Tensor, b: Tensor) -> Tensor:
    """``a @ b`` for batches of 3x3 matrices, elementwise in a fixed order (batch-independent)."""
    return a[..., :, 0:1] * b[..., 0:1, :] + a[..., :, 1:2] * b[..., 1:2, :] + a[..., :, 2:3] * b[..., 2:3, :]
