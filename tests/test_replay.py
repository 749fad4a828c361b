"""Exact replay across code changes: short flights of the first sweep episodes reproduce, bit for
bit, the per-episode RMSEs recorded in ``tests/data/replay_*.json`` (PD on the default vehicle, the
shipped policies wind-blind and wind-aware). A refactor must leave them unchanged; a physics or
checkpoint change re-records them with the command each file names (and says so in its commit)."""
import json
from pathlib import Path

import pytest

from quadwind_trl.evaluation.replay import mismatches, replay

DATA = Path(__file__).parent / "data"


# one mechanism for both sweeps; the vertical record (87 s, the longer patterns) runs with -m slow
@pytest.mark.parametrize("sweep", ["horizontal", pytest.param("vertical", marks=pytest.mark.slow)])
def test_sweep_slice_replays_bit_for_bit(sweep):
    record = json.loads((DATA / f"replay_{sweep}.json").read_text())
    start, stop = record["episodes"]
    flown = replay(record["sweep"], slice(start, stop), record["quick"])
    differ, total = mismatches(record["results"], flown)
    assert total == 3 * 3 * (stop - start)
    assert not differ, f"{len(differ)}/{total} values differ from the record made at {record['git_commit']}: {differ[:5]}"
