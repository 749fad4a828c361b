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

import functools
import math
from typing import NamedTuple

import torch
from torch import Tensor

from .operands import tracing

_MASK32 = 0xFFFFFFFF
_TWO_PI = 2.0 * math.pi


class _Numbers(NamedTuple):
    """The hash's numbers as 0-dim tensors on one device: an eager op converts a Python number
    operand at every use (``aten::_to_copy``), a tensor not at all (the integers are exact either
    way; the floats are the float32 values the conversion gives)."""

    mask: Tensor
    shift8: Tensor
    shift15: Tensor
    shift16: Tensor
    shift32: Tensor
    mix1: Tensor
    mix2: Tensor
    counter_mix: Tensor
    half: Tensor  # float32
    ulp24: Tensor  # float32 2^-24
    minus_two: Tensor  # float32
    two_pi: Tensor  # float32


def _make_numbers(device: torch.device) -> _Numbers:
    i = lambda v: torch.tensor(v, dtype=torch.int64, device=device)  # noqa: E731
    f = lambda v: torch.tensor(v, dtype=torch.float32, device=device)  # noqa: E731
    return _Numbers(i(_MASK32), i(8), i(15), i(16), i(32), i(0x7FEB352D), i(0x2C1B3C6D), i(0x27D4EB2F),
                    f(0.5), f(1.0 / 16777216.0), f(-2.0), f(_TWO_PI))


def _make_column_terms(num: int, device: torch.device) -> Tensor:
    """``column * 0x632BE5AB`` for the columns ``0 .. num - 1``."""
    return torch.arange(num, device=device, dtype=torch.int64) * 0x632BE5AB


_cached_numbers = functools.cache(_make_numbers)
_cached_column_terms = functools.cache(_make_column_terms)


# Eagerly the tensors are made once per device; traced, dynamo traces the maker itself (it would
# trace through a cache anyway, and say so in a warning at every compilation): the same graph
def _numbers(device: torch.device) -> _Numbers:
    return _make_numbers(device) if tracing() else _cached_numbers(device)


def _column_terms(num: int, device: torch.device) -> Tensor:
    return _make_column_terms(num, device) if tracing() else _cached_column_terms(num, device)


def _mix32(x: Tensor, c: _Numbers) -> Tensor:
    x = ((x ^ (x >> c.shift16)) * c.mix1) & c.mask
    x = ((x ^ (x >> c.shift15)) * c.mix2) & c.mask
    return x ^ (x >> c.shift16)


def stream_key(key: Tensor, stream: int) -> Tensor:
    """The part of :func:`hash_bits` that depends on the key and the stream alone: ``[...]``
    int64, an episode's constant where the key is its seed (a caller that draws every step
    keeps it and draws with :func:`keyed_normal`)."""
    key = key.to(torch.int64)
    c = _numbers(key.device)
    x = _mix32((key & c.mask) ^ ((stream * 0x9E3779B1) & _MASK32), c)
    return _mix32(x ^ ((key >> c.shift32) & c.mask), c)


def keyed_bits(keyed: Tensor, counter: Tensor | int, num: int) -> Tensor:
    """:func:`hash_bits` of a :func:`stream_key`."""
    c = _numbers(keyed.device)
    counter = torch.as_tensor(counter, dtype=torch.int64, device=keyed.device)
    x = _mix32((keyed ^ ((counter & c.mask) * c.counter_mix & c.mask)) & c.mask, c)
    x = _mix32(x ^ ((counter >> c.shift32) & c.mask), c)
    return _mix32((x.unsqueeze(-1) + _column_terms(num, keyed.device)) & c.mask, c)


def keyed_uniform(keyed: Tensor, counter: Tensor | int, num: int) -> Tensor:
    """:func:`hash_uniform` of a :func:`stream_key`."""
    c = _numbers(keyed.device)
    return ((keyed_bits(keyed, counter, num) >> c.shift8).to(torch.float32) + c.half) * c.ulp24


def keyed_normal(keyed: Tensor, counter: Tensor | int, num: int) -> Tensor:
    """:func:`hash_normal` of a :func:`stream_key`."""
    c = _numbers(keyed.device)
    u = keyed_uniform(keyed, counter, 2 * num)
    radius = torch.sqrt(c.minus_two * torch.log(u[..., :num]))
    return radius * torch.cos(c.two_pi * u[..., num:])


def hash_bits(key: Tensor, counter: Tensor | int, stream: int, num: int) -> Tensor:
    """``[..., num]`` uniformly distributed 32-bit integers (held in int64).

    ``key`` and ``counter`` are int64 tensors of the same (batch) shape, or ``counter`` a
    Python int; ``stream`` separates independent uses of one key (a sensor, the initial state).
    """
    return keyed_bits(stream_key(key, stream), counter, num)


def hash_uniform(key: Tensor, counter: Tensor | int, stream: int, num: int) -> Tensor:
    """``[..., num]`` float32 uniforms in the open interval (0, 1), 24-bit resolution."""
    return keyed_uniform(stream_key(key, stream), counter, num)


def hash_normal(key: Tensor, counter: Tensor | int, stream: int, num: int) -> Tensor:
    """``[..., num]`` float32 standard normals (Box-Muller on two hashed uniforms per value)."""
    return keyed_normal(stream_key(key, stream), counter, num)
