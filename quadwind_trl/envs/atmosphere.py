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
only, and the evaluation is elementwise products over the modes. Averaged over rotations the
skeleton is exactly isotropic, so the realised statistics pooled over episodes are the requested ones.

Stability anisotropy, exactly divergence-free: with ``v`` the unit isotropic field,
``F`` the mean-wind frame (along, across, up) at the episode's anchor altitude, ``R`` its
rotation and ``D = diag(1, sigma_v/sigma_u, sigma_w/sigma_u)``, the gust is
``sigma_u(z) F D R v(R^T D^-1 F^T x)``. Its Jacobian is ``F D R J_v R^T D^-1 F^T``, whose
trace is ``trace(J_v) = 0``: a linear change of coordinates paired with its inverse transpose
on the velocity (each mode's wavevector ``D^-1 k``, velocity ``D d``: still perpendicular). The
component variances become ``sigma_u^2 D^2``; the longitudinal component along the mean wind
is ``v``'s own, so L and the spectrum along the wind are unchanged. The only divergence left
is the product rule on ``sigma_u(z)``: ``sigma_u'/sigma_u * w`` (docs/atmosphere.md 2.3).

Layouts (``TurbulenceConfig.layout``):

* ``"full"``: dimensionless wavenumbers ``kappa = k L`` log-spaced over ``kappa_range``
  (default 2 pi / 60 to 800, i.e. k up to 2-16 rad/m for L = 400-50 m), amplitudes normalised
  so each component has exactly unit variance before scaling (the 1.4 % of variance above the
  top mode is folded into the resolved modes).
* ``"paper_grid"``: the paper's field: a bank of 64^3 cubes over 1200 m synthesised
  TurboGenPY's way on the grid (``synthesise_cube``), trilinear interpolation, periodic
  wrap-around; the same stretch and rotation map positions into the cube.

Intensity: ``sigma_u = I U(z) (max(z, z_ref)/z_ref)^(-e)`` with a mild
``e = TurbulenceConfig.intensity_altitude_exponent``.
"""
from __future__ import annotations

import math

import torch
from tensordict import TensorDict
from torch import Tensor

from ..config import TurbulenceConfig, WindProfileConfig
from .counter_rng import hash_bits, hash_normal, hash_uniform
from .rotations import quat_to_rotmat
from .tensordicts import entry, unchecked
from .trajectories import fixed_altitude_mask

VON_KARMAN_KE_L = 0.746834  # k_e L: peak wavenumber of the von Karman energy spectrum
VON_KARMAN_NORM = 1.452762  # makes the energy spectrum integrate to 3/2 sigma^2

_STREAM_ROTATION = 101
_STREAM_PHASE = 102
_STREAM_CUBE = 103
_STREAM_CUBE_OFFSET = 104


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


def _mode_widths(k: Tensor) -> Tensor:
    """Widths of log-spaced wavenumbers' bins (edges midway in log k)."""
    logk = k.log()
    mid = 0.5 * (logk[1:] + logk[:-1])
    edges = torch.cat((2 * logk[:1] - mid[:1], mid, 2 * logk[-1:] - mid[-1:])).exp()
    return edges[1:] - edges[:-1]


def synthesise_cube(cfg: TurbulenceConfig, length_scale: float, realisation: int) -> Tensor:
    """``[P, P, P, 3]`` float32 unit-sigma isotropic cube, TurboGenPY's construction (Saad et al.).

    ``P = cube_points`` cells over ``cube_size_m``, values at the cell centres ``(i + 1/2) h``;
    ``num_modes`` wavenumbers at the centres of equal bins from ``2 pi / cube_size_m`` to the
    grid's Nyquist ``pi / h``; directions uniform on the sphere, each mode's velocity
    perpendicular to its wavevector, phases uniform; amplitudes ``2 sqrt(E(k; L) dk)`` with no
    renormalisation, so the cube holds only the variance its k range holds. As in TurboGenPY
    the wavevectors are not commensurate with the box, so the wrapped field jumps at the faces.
    Computed in float64 from a generator seeded by (``skeleton_seed``, L, ``realisation``).
    """
    m, points, size = cfg.num_modes, cfg.cube_points, cfg.cube_size_m
    gen = torch.Generator().manual_seed(cfg.skeleton_seed + 1_000_003 * realisation + int(round(length_scale * 1000)))
    direction = torch.randn(m, 3, generator=gen, dtype=torch.float64)
    direction = direction / direction.norm(dim=-1, keepdim=True)
    velocity = torch.linalg.cross(direction, torch.randn(m, 3, generator=gen, dtype=torch.float64))
    velocity = velocity / velocity.norm(dim=-1, keepdim=True)
    phase = 2 * math.pi * torch.rand(m, generator=gen, dtype=torch.float64)
    k_lo, k_hi = 2 * math.pi / size, math.pi / (size / points)
    dk = (k_hi - k_lo) / m
    k = k_lo + dk * (torch.arange(m, dtype=torch.float64) + 0.5)
    amplitude = 2.0 * (von_karman_energy(k, length_scale) * dk).sqrt()
    wavevector = k.unsqueeze(-1) * direction  # [M, 3]
    centres = (torch.arange(points, dtype=torch.float64) + 0.5) * (size / points)
    gx, gy = torch.meshgrid(centres, centres, indexing="ij")
    cube = torch.empty(points, points, points, 3, dtype=torch.float64)
    # elementwise sums, never a matmul: the bank must not depend on BLAS's thread count (replay)
    for iz, z in enumerate(centres):  # one z-plane at a time: [P * P, M] phases
        theta = phase + gx.reshape(-1, 1) * wavevector[:, 0] + gy.reshape(-1, 1) * wavevector[:, 1] + float(z) * wavevector[:, 2]
        modes = torch.cos(theta) * amplitude
        cube[:, :, iz] = torch.stack([(modes * velocity[:, c]).sum(-1) for c in range(3)], -1).reshape(points, points, 3)
    return cube.to(torch.float32)


class Atmosphere:
    """Mean profile plus turbulence for a batch of episodes.

    Pure methods over two TensorDicts: the per-episode ``params`` (the profile, the regime's
    ratios, the field's maps, its mode phases and amplitudes or its cube: written once at reset)
    and the dynamic ``state`` (the advected air offset ``air_offset``).
    """

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

        # the full layout's shared skeleton (the grid layout synthesises its own cubes' modes)
        lo, hi = turbulence.kappa_range
        kappa = torch.logspace(math.log10(lo), math.log10(hi), m, dtype=torch.float64)
        energy = von_karman_energy(kappa, 1.0) * _mode_widths(kappa)
        amp = 2.0 * energy.sqrt()
        amp = amp * math.sqrt(3.0 / (0.5 * (amp**2).sum()))  # unit variance per component
        self.shared_amplitude = amp.to(torch.float32).to(self.device)
        # dimensionless wavevectors kappa_m d_m (rad per length scale L: divided by L per episode)
        self.wavevector = (kappa.unsqueeze(-1) * direction).to(torch.float32).to(self.device)  # [M, 3]
        self.velocity_dir = velocity_dir.to(torch.float32).to(self.device)  # [M, 3], perpendicular to wavevector
        self._velocity_dir_t = self.velocity_dir.T.contiguous()  # [3, M]
        self.cube_bank: Tensor | None = None
        if turbulence.layout == "paper_grid":
            self.cube_bank = torch.stack(
                [synthesise_cube(turbulence, length, realisation).to(self.device)
                 for length in turbulence.cube_length_scales_m for realisation in range(turbulence.cube_bank_size)]
            )  # fmt: skip  # [len(cube_length_scales_m) * cube_bank_size, P, P, P, 3]
            self._cube_log_lengths = torch.tensor(turbulence.cube_length_scales_m, device=self.device).log()
        self.stability_ratios = torch.tensor(
            [(1.0, v, w) for v, w in turbulence.stability_ratios], dtype=torch.float32, device=self.device
        )
        self._fixed_altitude = fixed_altitude_mask(self.device)

    # --- per-episode parameters ---------------------------------------------------------------

    def init(self, scenario: TensorDict | dict[str, Tensor]) -> tuple[TensorDict, TensorDict]:
        """``(params, state)`` of a batch of episodes from their scenario fields ``[N]``: the
        per-episode wind parameters, and the advection state (the air offset, zero at the start)."""
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
        if self.turbulence.anisotropy == "stretch":
            field_out = _matmul3(frame * ratios.unsqueeze(-2), rotation)  # F D R
            field_in = _matmul3(rotation.transpose(-1, -2), frame.transpose(-1, -2) / ratios.unsqueeze(-1))  # R^T D^-1 F^T
        else:  # "local_scaling": the isotropic field, rotated into the reference-height wind frame
            field_out = _matmul3(_rot_z(-torch.sin(base_from), -torch.cos(base_from)), rotation)
            field_in = field_out.transpose(-1, -2)
        params = {
            "wind_speed_ref": scenario["wind_speed_ref_m_s"].to(torch.float32),
            "wind_from0": base_from,
            "shear_alpha": scenario["shear_alpha"].to(torch.float32),
            "veer_rad_per_m": veer,
            "intensity": scenario["turb_intensity"].to(torch.float32),
            "ratios": ratios,
            "field_in": field_in,
            "field_out": field_out,
        }
        length = scenario["turb_length_scale_m"].to(torch.float32)
        if self.cube_bank is None:
            params["phase"] = 2 * math.pi * hash_uniform(seed, 0, _STREAM_PHASE, self.turbulence.num_modes)
            params["amplitude"] = self.shared_amplitude.expand(n, -1).contiguous()
            params["k_scale"] = (1.0 / length).unsqueeze(-1)
        else:
            # the nearest length scale of the bank (in log L), one of its realisations by seed,
            # and a uniform offset into the periodic cube: episodes sharing a cube still fly
            # through different parts of it, in different orientations (R)
            nearest = (length.log().unsqueeze(-1) - self._cube_log_lengths).abs().argmin(-1)
            bank = self.turbulence.cube_bank_size
            pick = hash_bits(seed, 0, _STREAM_CUBE, 1)[..., 0] % bank
            params["cube"] = nearest * bank + pick
            params["cube_offset"] = self.turbulence.cube_size_m * hash_uniform(seed, 0, _STREAM_CUBE_OFFSET, 3)
        state = TensorDict(air_offset=torch.zeros(n, 3, device=seed.device), batch_size=[n])
        return TensorDict(params, batch_size=[n]), state

    # --- evaluation ---------------------------------------------------------------------------

    def _profile(self, params: TensorDict, z: Tensor) -> tuple[Tensor, Tensor]:
        """Capped mean speed and the "from" direction (rad) at altitudes ``z``."""
        z_ref = self.wind.reference_height_m
        zc = z.clamp_min(z_ref)
        # (zc / z_ref) ** alpha written as exp(alpha log(.)): torch's CPU pow (and atan2) round
        # differently in the vectorised body and the scalar tail of a kernel, which made a row's
        # wind depend on the batch size; exp and log do not (tests/test_atmosphere.py)
        speed = entry(params, "wind_speed_ref") * torch.exp(entry(params, "shear_alpha") * torch.log(zc / z_ref))
        speed = speed.clamp_max(self.wind.max_horizontal_wind_m_s)
        wind_from = entry(params, "wind_from0") + entry(params, "veer_rad_per_m") * (zc - z_ref)
        return speed, wind_from

    def mean_wind(self, params: TensorDict, z: Tensor) -> Tensor:
        """``[N, 3]`` turbulence-free mean wind (ENU) at altitudes ``z`` ``[N]``."""
        speed, wind_from = self._profile(params, z)
        return torch.stack((-speed * torch.sin(wind_from), -speed * torch.cos(wind_from), torch.zeros_like(speed)), -1)

    def unit_gust(self, params: TensorDict, field_pos: Tensor) -> Tensor:
        """The episode's anisotropic gust (ENU) per unit sigma_u, at positions in the frozen field's frame.

        ``F D R v(R^T D^-1 F^T x)``: ``v`` the unit-variance mode sum in the skeleton frame, ``R``
        the episode's rotation, ``D = diag(1, sigma_v / sigma_u, sigma_w / sigma_u)`` its
        regime's ratios in the anchor frame ``F`` (``init``). ``field_pos`` is ``[N, 3]``
        (or ``[..., N, 3]``: several points per episode). Written with elementwise operations in
        a fixed order and one sum over each row's contiguous modes, never a matmul: BLAS picks
        kernels (and summation orders) by the batch size, which made a row's wind depend on how
        many rows shared its batch (tests/test_atmosphere.py).
        """
        m_in, m_out = entry(params, "field_in"), entry(params, "field_out")
        x, y, z = field_pos[..., 0], field_pos[..., 1], field_pos[..., 2]
        if self.cube_bank is not None:
            local = [x * m_in[..., c, 0] + y * m_in[..., c, 1] + z * m_in[..., c, 2] + params["cube_offset"][..., c] for c in range(3)]
            bx, by, bz = self._interpolate_cube(params["cube"], local).unbind(-1)
            return torch.stack([m_out[..., r, 0] * bx + m_out[..., r, 1] * by + m_out[..., r, 2] * bz for r in range(3)], -1)
        # per row, once: the position in the skeleton frame in length scales, [..., N, M, 3]; the
        # [..., N, M] phase below then reads three numbers per row (before, the compiled kernel
        # recomputed each row's rotation for every mode). The three components of each matrix
        # product at once: the same operations on every element, a third of the eager ops
        local = x.unsqueeze(-1) * m_in[..., 0] + y.unsqueeze(-1) * m_in[..., 1] + z.unsqueeze(-1) * m_in[..., 2]
        scaled = local.unsqueeze(-2) * entry(params, "k_scale").unsqueeze(-1)
        w = self.wavevector
        # theta = phase + sum_c scaled_c kappa_m d_mc: the operations and order of the per-mode
        # form, so the same bits eager and compiled
        theta = entry(params, "phase") + scaled[..., 0] * w[:, 0] + scaled[..., 1] * w[:, 1] + scaled[..., 2] * w[:, 2]
        modes = torch.cos(theta) * entry(params, "amplitude")
        bx, by, bz = ((modes * self._velocity_dir_t[c]).sum(-1, keepdim=True) for c in range(3))  # skeleton frame
        return m_out[..., 0] * bx + m_out[..., 1] * by + m_out[..., 2] * bz

    def _interpolate_cube(self, cube: Tensor, local: list[Tensor]) -> Tensor:
        """Trilinear interpolation ``[..., N, 3]`` of bank cubes ``cube`` ``[N]`` at skeleton-frame
        positions ``local`` (three ``[..., N]``), wrapped periodically (the paper's wrap-around).

        Cube values sit at cell centres ``(i + 1/2) h``; a position's cell and weights come from
        ``floor`` and its remainder, the eight corners from one gather each, combined in a fixed
        order (batch-independent, like the mode sum).
        """
        points = self.turbulence.cube_points
        h = self.turbulence.cube_size_m / points
        flat = self.cube_bank.reshape(-1, 3)
        base = cube * points**3
        index, weight = [], []
        for c in range(3):
            g = local[c] / h - 0.5
            g0 = torch.floor(g)
            frac = g - g0
            i0 = torch.remainder(g0.to(torch.int64), points)
            index.append((i0, torch.remainder(i0 + 1, points)))
            weight.append((1.0 - frac, frac))
        out = 0.0
        for a in range(2):
            for b in range(2):
                for d in range(2):
                    row = base + (index[0][a] * points + index[1][b]) * points + index[2][d]
                    w = weight[0][a] * weight[1][b] * weight[2][d]
                    out = out + w.unsqueeze(-1) * flat[row]
        return out

    def turbulence_sigma(self, params: TensorDict, mean: Tensor, z: Tensor) -> Tensor:
        """``[N, 3]`` requested standard deviations at altitude ``z``, in the episode's anchor frame.

        (along, across, up) of the mean wind at the anchor altitude (``init``); the gust
        is ``sigma_u`` times ``unit_gust``, whose ensemble variances are ``(1, r_v^2, r_w^2)``.
        """
        z_ref = self.wind.reference_height_m
        speed = torch.sqrt(mean[..., 0] * mean[..., 0] + mean[..., 1] * mean[..., 1])
        decay = torch.exp(-self.turbulence.intensity_altitude_exponent * torch.log(z.clamp_min(z_ref) / z_ref))
        return (entry(params, "intensity") * speed * decay).unsqueeze(-1) * entry(params, "ratios")

    def sample(self, params: TensorDict, state: TensorDict, pos: Tensor, dt: float) -> tuple[Tensor, Tensor, TensorDict]:
        """Mean and total wind ``[N, 3]`` at ``pos``; the state advected by ``dt`` seconds.

        The returned wind applies over the coming ``dt`` (the simulator holds it over the
        control step's physics substeps).
        """
        z = pos[..., 2]
        mean = self.mean_wind(params, z)
        total = mean
        field_pos = pos - entry(state, "air_offset")
        if self.turbulence.enabled and self.turbulence.anisotropy == "stretch":
            sigma_u = self.turbulence_sigma(params, mean, z)[..., :1]
            total = mean + sigma_u * self.unit_gust(params, field_pos)
        elif self.turbulence.enabled:
            total = mean + self._locally_scaled_gust(params, field_pos, mean, z)
        if self.wind.cap_applies_to == "total":
            total = _cap_horizontal(total, self.wind.max_horizontal_wind_m_s)
        state = unchecked(state.batch_size, dict(air_offset=entry(state, "air_offset") + dt * mean))
        return mean, total, state

    def _locally_scaled_gust(self, params: TensorDict, field_pos: Tensor, mean: Tensor, z: Tensor) -> Tensor:
        """``anisotropy="local_scaling"``: the isotropic unit field's components scaled by the
        regime's sigmas in the local mean-wind frame at ``z`` (rotate in, scale, rotate out). Not
        divergence-free; kept, operation for operation, for configs saved before the stretch."""
        iso = self.unit_gust(params, field_pos)  # isotropic: no stretch in its maps
        sigma = self.turbulence_sigma(params, mean, z)
        # (c, s): the unit vector the mean wind blows towards (no atan2: see _profile)
        _, wind_from = self._profile(params, z)
        c, s = -torch.sin(wind_from), -torch.cos(wind_from)
        along = c * iso[..., 0] + s * iso[..., 1]
        across = -s * iso[..., 0] + c * iso[..., 1]
        along, across, up = sigma[..., 0] * along, sigma[..., 1] * across, sigma[..., 2] * iso[..., 2]
        return torch.stack((c * along - s * across, s * along + c * across, up), -1)


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
