"""Re-fly a slice of an evaluation sweep and record (or check) every per-episode RMSE to the bit.

    python recipes/replay_slice.py --out runs/replay/before.json                 # horizontal 0:45
    python recipes/replay_slice.py --compare results/replay/horizontal_0-45.json # ~6 min, 1 thread
    python recipes/replay_slice.py --quick --episodes 0:3 --out tests/data/replay_horizontal.json

Flown: PD on the default vehicle (``EnvConfig()``), and the shipped policy of the sweep's regime
wind-blind and wind-aware (in the env its checkpoint records), all on the same episodes with one
batch of the slice's size. Values are stored as ``float.hex`` strings, so a comparison is exact,
with the platform that flew them: on that platform a refactor that claims "no physics change"
must reproduce every one of them; on another, ``--compare`` reports the deviations against the
cross-platform tolerance (docs/simulator.md, "Exact replay").
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

from quadwind_trl.evaluation.replay import CROSS_PLATFORM_RTOL, compare_records, replay, replay_verdict
from quadwind_trl.manifest import command_line, git_commit, platform_info, write_json
from quadwind_trl.outputs import hold_for_command
from quadwind_trl.regimes import SWEEPS

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sweep", default="horizontal", choices=list(SWEEPS))
    parser.add_argument("--episodes", default="0:45", help="a slice START:STOP of the sweep's episodes")
    parser.add_argument("--quick", action="store_true", help="the sweep's smoke subset on short flights")
    parser.add_argument("--out", type=Path, default=None, help="write the record here")
    parser.add_argument("--compare", type=Path, default=None, help="a record to check bit for bit")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--pattern-s", type=float, default=None,
                        help="shorten the fixed-altitude patterns to this many seconds (a cheaper check)")
    parser.add_argument("--eager", action="store_true",
                        help="fly the policies on the eager simulator step (default: the step each trained on)")
    args = parser.parse_args()
    if args.out is not None:
        hold_for_command(args.out, what="replay record", hint="wait for it to finish, or choose another --out")
    torch.set_num_threads(args.threads)
    start, stop = (int(x) for x in args.episodes.split(":"))
    if args.compare is not None:  # fly exactly what the record flew
        ref = json.loads(args.compare.read_text())
        args.sweep, args.quick, (start, stop) = ref["sweep"], ref["quick"], ref["episodes"]
        args.eager, args.pattern_s = ref.get("eager", False), ref.get("pattern_s")
    t0 = time.perf_counter()
    flown = replay(args.sweep, slice(start, stop), args.quick, compile_step=False if args.eager else None,
                   pattern_s=args.pattern_s)
    record = {"sweep": args.sweep, "episodes": [start, stop], "quick": args.quick, "eager": args.eager,
              "pattern_s": args.pattern_s, "results": flown,
              "command": command_line(sys.argv), "git_commit": git_commit(), "platform": platform_info(), "wall_time_s": time.perf_counter() - t0}
    if args.out is not None:
        write_json(args.out, record)
        print(f"wrote {args.out}")
    if args.compare is not None:
        holds, verdict = replay_verdict(compare_records(ref["results"], flown), ref.get("platform"),
                                        CROSS_PLATFORM_RTOL.get((ref["sweep"], ref["quick"])))
        print(f"{args.sweep} episodes {start}:{stop} against {args.compare} (recorded at {ref['git_commit']}): {verdict}")
        if not holds:
            sys.exit(1)

if __name__ == "__main__":
    main()
