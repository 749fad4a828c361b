"""Closed-form planar paths ``P(s)`` the built-in patterns are made of.

Each takes a 0-d float64 tensor ``s`` (arc length in m, or phase in rad) and its sizes, and
returns ``[2]`` (x east, y north; m); they are differentiated, never hand-derived.
"""
from __future__ import annotations

import math

import torch
from torch import Tensor


def circle(s: Tensor, radius: float) -> Tensor:
    """Counter-clockwise circle through the origin's south point, by arc length."""
    return radius * torch.stack((torch.sin(s / radius), -torch.cos(s / radius)))


def stadium(s: Tensor, straight: float, radius: float) -> Tensor:
    """Racetrack: two straights joined by 180-degree turns, counter-clockwise, by arc length."""
    half_turn = math.pi * radius
    perimeter = 2 * straight + 2 * half_turn
    u = torch.remainder(s, perimeter)
    leg1 = torch.stack((-straight / 2 + u, u * 0 - radius))
    a = (u - straight) / radius - math.pi / 2
    turn1 = torch.stack((straight / 2 + radius * torch.cos(a), radius * torch.sin(a)))
    v = u - straight - half_turn
    leg2 = torch.stack((straight / 2 - v, v * 0 + radius))
    b = (u - 2 * straight - half_turn) / radius + math.pi / 2
    turn2 = torch.stack((-straight / 2 + radius * torch.cos(b), radius * torch.sin(b)))
    return torch.where(
        u < straight,
        leg1,
        torch.where(u < straight + half_turn, turn1, torch.where(u < 2 * straight + half_turn, leg2, turn2)),
    )


def raster(s: Tensor, leg: float, spacing: float, legs: int) -> Tensor:
    """Lawnmower: ``legs`` parallel legs along x joined by semicircular turns, by arc length."""
    radius = spacing / 2
    cycle = leg + math.pi * radius
    y0 = -(legs - 1) * spacing / 2
    i = torch.clamp(torch.floor(s / cycle), 0, legs - 1)
    u = s - i * cycle
    even = torch.remainder(i, 2) == 0
    y_leg = y0 + i * spacing
    straight = torch.stack((torch.where(even, -leg / 2 + u, leg / 2 - u), y_leg))
    phi = (u - leg) / radius
    ang = torch.where(even, -math.pi / 2 + phi, -math.pi / 2 - phi)
    cx = torch.where(even, u * 0 + leg / 2, u * 0 - leg / 2)
    turn = torch.stack((cx + radius * torch.cos(ang), y_leg + radius + radius * torch.sin(ang)))
    return torch.where((u < leg) | (i == legs - 1), straight, turn)


def lemniscate(s: Tensor, half_length: float) -> Tensor:
    """Figure-eight (lemniscate of Gerono), by phase."""
    return torch.stack((half_length * torch.sin(s), 0.5 * half_length * torch.sin(2 * s)))


def rose(s: Tensor, radius: float) -> Tensor:
    """Four-lobed cloverleaf r = A cos(2 theta), by phase."""
    return radius * torch.cos(2 * s) * torch.stack((torch.cos(s), torch.sin(s)))


def still(s: Tensor) -> Tensor:
    """The origin (hover and the straight vertical climb)."""
    return torch.stack((s * 0, s * 0))
