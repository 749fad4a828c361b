"""The toy pipeline's first stages on a simulated two-node Ray cluster: where each stage ran.

    python bench/pipeline_two_nodes.py                 # data + estimator stages of both regimes
    python bench/pipeline_two_nodes.py --cpus-per-node 1 --out /tmp/two_nodes

``ray.cluster_utils.Cluster`` starts a head node and a second node on this machine, each with
``--cpus-per-node`` CPUs (two Ray nodes with their own raylets and workers, sharing this file
system as a real cluster shares its network one); ``recipes/reproduce.py --quick --executor ray
--address HEAD`` then runs the stages (``--only``), and its ``pipeline_times.json`` says which
node ran each one. With one CPU per node, the two regimes' independent chains can only run at
once by running on different nodes.

One parseable line per stage: ``stage NAME ray_node=... wall_s=... load_1min=... peak_rss_mib=...``,
then ``nodes_used=K of 2 pipeline_wall_s=...``.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from machine import load_1min, machine_line

ROOT = Path(__file__).resolve().parent.parent
STAGES = ("data-horizontal", "data-vertical", "estimator-horizontal", "estimator-vertical")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cpus-per-node", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path("/tmp/quadwind_two_nodes"),
                        help="the toy run's directory (emptied first)")
    parser.add_argument("--only", nargs="+", default=list(STAGES), help="the stages to run")
    args = parser.parse_args()
    if args.cpus_per_node < 1:
        parser.error(f"--cpus-per-node={args.cpus_per_node}: allowed range: >= 1")
    from ray.cluster_utils import Cluster

    print(machine_line(threads=1, workers=2 * args.cpus_per_node), flush=True)
    subprocess.run(["rm", "-rf", str(args.out)], check=True)
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": args.cpus_per_node})
    cluster.add_node(num_cpus=args.cpus_per_node)
    try:
        cluster.wait_for_nodes()
        t0 = time.perf_counter()
        subprocess.run([sys.executable, str(ROOT / "recipes" / "reproduce.py"), "--quick", "--out", str(args.out),
                        "--executor", "ray", "--address", cluster.address, "--only", *args.only], cwd=ROOT, check=True)
        wall = time.perf_counter() - t0
    finally:
        cluster.shutdown()
    record = json.loads((args.out / "pipeline_times.json").read_text())
    for name, r in record.items():
        print(f"stage {name} ray_node={r['ray_node']} wall_s={r['wall_time_s']} load_1min={r['load_average_1min']} "
              f"peak_rss_mib={r['peak_rss_mib']}")
    print(f"nodes_used={len({r['ray_node'] for r in record.values()})} of 2 pipeline_wall_s={wall:.0f} "
          f"load_1min={load_1min():.2f}")


if __name__ == "__main__":
    main()
