"""What another processor changes, and what exact cross-machine replay of the policy would cost.

    python bench/kernel_paths.py

Runs the same probe under each ATen CPU kernel path this machine supports (``ATEN_CPU_CAPABILITY``
= ``default``, ``avx2``, ``avx512``; each in its own process, one thread): what a processor with
that instruction set runs. Per operation the simulator, the policy or the estimator uses, it prints
whether the result is bit-identical to this machine's native path; then, for the shipped
horizontal policy's MLP at N = 1, 7 and 225 (a sweep batch), whether its output is, as
``nn.Linear`` (BLAS) and as a fixed-order linear (exact products, then a fixed pairwise tree of
elementwise adds: no reduction whose order depends on the vector width), and the time of each.
Figures: docs/benchmarks.md ("Kernel paths and exact replay"); the reading: docs/simulator.md
("Exact replay").
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import time

import torch
from machine import machine_line

PATHS = ("avx512", "avx2", "default")
SIZES = (1, 7, 225)


def _digest(t: torch.Tensor) -> str:
    return hashlib.sha1(t.detach().contiguous().numpy().tobytes()).hexdigest()[:12]


def tree_sum(p: torch.Tensor) -> torch.Tensor:
    """Sum over the last dim in a fixed pairwise order, with elementwise adds only."""
    while p.shape[-1] > 1:
        if p.shape[-1] % 2:
            p = torch.cat((p, torch.zeros_like(p[..., :1])), -1)
        half = p.shape[-1] // 2
        p = p[..., :half] + p[..., half:]
    return p[..., 0]


def fixed_order_mlp(mlp: torch.nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    for m in mlp:
        x = tree_sum(x.unsqueeze(-2) * m.weight) + m.bias if isinstance(m, torch.nn.Linear) else m(x)
    return x


def _timed(fn, repeats: int = 20) -> float:
    fn()
    t0 = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - t0) / repeats * 1e6


def inputs(*shape: int, seed: int) -> torch.Tensor:
    """Values in [-4, 4) from integer hashing (exact on every kernel path, unlike ``torch.randn``,
    whose scalar and vectorised samplers differ)."""
    k = torch.arange(seed, seed + torch.Size(shape).numel(), dtype=torch.int64)
    return ((k * 2654435761) % (1 << 21)).to(torch.float32).reshape(shape) / (1 << 18) - 4.0


@torch.no_grad()
def probe() -> dict:
    """Digests of each operation and of the policy MLP both ways, with timings (this process)."""
    from quadwind_trl.manifest import CHECKPOINT_DIR
    from quadwind_trl.rl.policy import load_policy

    x, w = inputs(225, 256, seed=0), inputs(256, seed=1 << 20)
    ops = {"mul+add": lambda: x * w + x, "sqrt": lambda: x.abs().sqrt(), "exp": lambda: x.exp(), "sin": lambda: x.sin(),
           "atan2": lambda: torch.atan2(x, w.expand_as(x)), "tanh": lambda: x.tanh(), "sigmoid": lambda: x.sigmoid(),
           "gelu": lambda: torch.nn.functional.gelu(x), "sum(-1)": lambda: x.sum(-1),
           "softmax": lambda: x.softmax(-1), "layer_norm": lambda: torch.nn.functional.layer_norm(x, (256,)),
           "matmul": lambda: x @ x.T}
    out = {"capability": torch.backends.cpu.get_cpu_capability(), "ops": {k: _digest(f()) for k, f in ops.items()}}
    mlp = load_policy(CHECKPOINT_DIR / "policy_horizontal.pt")[0].module[0].module[0]
    for n in SIZES:
        obs = inputs(n, mlp[0].in_features, seed=n) / 4
        out[f"mlp N={n}"] = {"linear": _digest(mlp(obs)), "fixed": _digest(fixed_order_mlp(mlp, obs)),
                             "linear_us": _timed(lambda: mlp(obs)), "fixed_us": _timed(lambda: fixed_order_mlp(mlp, obs))}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--probe", action="store_true", help="run the probe in this process and print it as JSON")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.probe:
        print(json.dumps(probe()))
        return
    print(machine_line(threads=1), flush=True)
    native = probe()
    print(f"native kernel path: {native['capability']}")
    for path in PATHS:
        env = {**os.environ, "ATEN_CPU_CAPABILITY": path}
        run = subprocess.run([sys.executable, __file__, "--probe"], env=env, capture_output=True, text=True, check=True)
        other = json.loads(run.stdout.strip().splitlines()[-1])
        same = [k for k, v in other["ops"].items() if v == native["ops"][k]]
        differ = [k for k in other["ops"] if k not in same]
        print(f"kernel_path {path} -> {other['capability']}: ops bit-identical to native: {', '.join(same) or 'none'}; "
              f"differ: {', '.join(differ) or 'none'}")
        for n in SIZES:
            o, m = other[f"mlp N={n}"], native[f"mlp N={n}"]
            print(f"kernel_path {path} policy_mlp N={n}: nn.Linear {'same' if o['linear'] == m['linear'] else 'DIFFERS'} "
                  f"({o['linear_us']:.0f} us), fixed-order {'same' if o['fixed'] == m['fixed'] else 'DIFFERS'} "
                  f"({o['fixed_us']:.0f} us, {o['fixed_us'] / o['linear_us']:.0f}x)")


if __name__ == "__main__":
    main()
