"""The peer row of ``bench/env_throughput.py``: crazyflow 0.4 (JAX) at the same N, same timing.

Runs inside its own virtual environment (JAX and MuJoCo are not dependencies of quadwind_trl);
``bench/env_throughput.py --peer crazyflow`` creates it on demand under ``.cache/peer-crazyflow``
and calls this script there. One control step is what quadwind_trl calls one: a 100 Hz state
(position) command and 5 dynamics steps at 500 Hz (crazyflow's defaults: first-principles
dynamics, explicit Euler, Mellinger cascade; no wind, no turbulence, no sensors). XLA's CPU thread
pool is limited to ``--threads`` (flags set before JAX is imported). Prints::

    peer_crazyflow N=4096 threads=1 control_steps_per_s=... load_1min=...
"""
from __future__ import annotations

import argparse
import os
import time


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[4096])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    if args.threads == 1:
        os.environ["XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
    import jax
    import numpy as np
    from crazyflow.sim import Sim

    for n in args.sizes:
        sim = Sim(n_worlds=n, n_drones=1, control="state", freq=500, state_freq=100)
        target = np.zeros((n, 1, 16), dtype=np.float32)
        target[..., 2] = 1.0  # hover 1 m up
        sim.reset()
        sim.state_control(target)

        def control_step() -> None:
            sim.state_control(target)
            sim.step(5)

        for _ in range(3):  # compilation
            control_step()
        jax.block_until_ready(sim.data.states.pos)
        steps, start = 0, time.perf_counter()
        while time.perf_counter() - start < args.seconds:
            for _ in range(10):
                control_step()
            jax.block_until_ready(sim.data.states.pos)
            steps += 10
        rate = steps * n / (time.perf_counter() - start)
        print(f"peer_crazyflow N={n} threads={args.threads} control_steps_per_s={rate:.0f} "
              f"load_1min={os.getloadavg()[0]:.2f} jax={jax.__version__}", flush=True)


if __name__ == "__main__":
    main()
