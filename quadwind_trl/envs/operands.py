"""The numbers a step combines with its tensors: 0-dim tensors eagerly, Python numbers while
``torch.compile`` traces the step.

Eagerly, an op with a Python number operand converts the number at every call
(``aten::_to_copy``, at small batches about as costly as the op), while a 0-dim tensor of the
operand's dtype, holding the value that conversion gives, computes the same bits without it.
Traced, the two are not alike: inductor writes a number into its kernels as a literal and makes
a tensor one more kernel input, and a graph with other inputs is fused and vectorised
differently. A sine or cosine that moves between a vectorised loop and a scalar one rounds
differently in its last bit, so the compiled step would no longer re-fly the results recorded
with it. What is traced therefore keeps the numbers.
"""
from __future__ import annotations

from typing import TypeVar

import torch

T = TypeVar("T")


def tracing() -> bool:
    """Whether ``torch.compile`` (or ``torch.export``) is tracing the calling code."""
    return torch.compiler.is_compiling()


def operands(eager: T, traced: T) -> T:
    """``eager`` (tensors made once) when running eagerly, ``traced`` (the same numbers as Python
    numbers) while traced."""
    return traced if tracing() else eager
