"""Counter-based (stateless) random numbers for exact replay.

Row ``i`` of every draw is a pure function of ``(key[i], counter[i], stream, column)``: it does
not depend on the batch size, on the row's position in the batch, or on what other rows did.
That is what lets a paired evaluation replay one episode spec under several controllers and get
identical wind and sensor noise (docs/architecture.md, "Exact replay").

The hash is a 32-bit xorshift-multiply integer mixer in the style of ``lowbias32`` (the first
multiplier, 0x7FEB352D, is lowbias32's; the second, 0x2C1B3C6D, is not lowbias32's 0x846CA68B:
the streams are defined by these constants, so they stay; tests/test_sensors.py checks the
statistics), evaluated in int64 with every product masked to 32 bits, so no intermediate
overflows int64 on any device.
"""
from __future__ import annotations

import math

import torch
from torch import Tensor

_MASK32 = 0xFFFFFFFF
_TWO_PI = 2.0 * math.pi


def _mix32(x: Tensor) -> Tensor:
    x = ((x ^ (x >> 16)) * 0x7FEB352D) & _MASK32
    x = ((x ^ (x >> 15)) * 0x2C1B3C6D) & _MASK32
    return x ^ (x >> 16)


def hash_bits(key: Tensor, counter: Tensor | int, stream: int, num: int) -> Tensor:
    """``[..., num]`` uniformly distributed 32-bit integers (held in int64).

    ``key`` and ``counter`` are int64 tensors of the same (batch) shape, or ``counter`` a
    Python int; ``stream`` separates independent uses of one key (a sensor, the initial state).
    """
    key = key.to(torch.int64)
    counter = torch.as_tensor(counter, dtype=torch.int64, device=key.device)
    cols = torch.arange(num, device=key.device, dtype=torch.int64)
    x = _mix32((key & _MASK32) ^ ((stream * 0x9E3779B1) & _MASK32))
    x = _mix32(x ^ ((key >> 32) & _MASK32))
    x = _mix32((x ^ ((counter & _MASK32) * 0x27D4EB2F & _MASK32)) & _MASK32)
    x = _mix32(x ^ ((counter >> 32) & _MASK32))
    x = _mix32((x.unsqueeze(-1) + cols * 0x632BE5AB) & _MASK32)
    return x


def hash_uniform(key: Tensor, counter: Tensor | int, stream: int, num: int) -> Tensor:
    """``[..., num]`` float32 uniforms in the open interval (0, 1), 24-bit resolution."""
    bits = hash_bits(key, counter, stream, num)
    return ((bits >> 8).to(torch.float32) + 0.5) * (1.0 / 16777216.0)


def hash_normal(key: Tensor, counter: Tensor | int, stream: int, num: int) -> Tensor:
    """``[..., num]`` float32 standard normals (Box-Muller on two hashed uniforms per value)."""
    u = hash_uniform(key, counter, stream, 2 * num)
    radius = torch.sqrt(-2.0 * torch.log(u[..., :num]))
    return radius * torch.cos(_TWO_PI * u[..., num:])
