"""Re-fly a slice of an evaluation sweep and record (or check) every per-episode RMSE to the bit.

    python recipes/replay_slice.py --out runs/replay/before.json                 # horizontal 0:45
    python recipes/replay_slice.py --compare results/replay/horizontal_0-45.json # ~6 min, 1 thread
    python recipes/replay_slice.py --quick --episodes 0:3 --out tests/data/replay_horizontal.json

Flown: PD on the default vehicle (``EnvConfig()``), and the shipped policy of the sweep's regime
wind-blind and wind-aware (in the env its checkpoint records), all on the same episodes with one
batch of the slice's size. Values are stored as ``float.hex`` strings, so a comparison is exact:
a refactor that claims "no physics change" must reproduce every one of them.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

from quadwind_trl.evaluation.replay import mismatches, replay
from quadwind_trl.manifest import command_line, git_commit, write_json
from quadwind_trl.regimes import SWEEPS

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sweep", default="horizontal", choices=list(SWEEPS))
    parser.add_argument("--episodes", default="0:45", help="a slice START:STOP of the sweep's episodes")
    parser.add_argument("--quick", action="store_true", help="the sweep's smoke subset on short flights")
    parser.add_argument("--out", type=Path, default=None, help="write the record here")
    parser.add_argument("--compare", type=Path, default=None, help="a record to check bit for bit")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    start, stop = (int(x) for x in args.episodes.split(":"))
    if args.compare is not None:  # fly exactly what the record flew
        ref = json.loads(args.compare.read_text())
        args.sweep, args.quick, (start, stop) = ref["sweep"], ref["quick"], ref["episodes"]
    t0 = time.perf_counter()
    flown = replay(args.sweep, slice(start, stop), args.quick)
    record = {"sweep": args.sweep, "episodes": [start, stop], "quick": args.quick, "results": flown,
              "command": command_line(sys.argv), "git_commit": git_commit(), "wall_time_s": time.perf_counter() - t0}
    if args.out is not None:
        write_json(args.out, record)
        print(f"wrote {args.out}")
    if args.compare is not None:
        differ, total = mismatches(ref["results"], flown)
        print(f"{args.sweep} episodes {start}:{stop}: {total - len(differ)}/{total} values bit-identical to "
              f"{args.compare} (recorded at {ref['git_commit']})")
        if differ:
            print("differ:", differ[:10])
            sys.exit(1)


if __name__ == "__main__":
    main()
