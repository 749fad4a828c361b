"""The headroom study flies the ablation's base law through the error budget, and its split adds up."""
import json

import pytest

from quadwind_trl.estimator import load_estimator
from quadwind_trl.evaluation import ablation
from quadwind_trl.evaluation.tracking import sweep_setup
from quadwind_trl.manifest import CHECKPOINT_DIR
from quadwind_trl.regimes import SWEEPS
from quadwind_trl.studies.headroom import AXES, SECTION, headroom, split
from quadwind_trl.studies.section import ReportContext

REGIME = "horizontal"
POLICY = CHECKPOINT_DIR / f"policy_{REGIME}.pt"


@pytest.fixture(scope="module")
def flown():
    """Three smoke episodes of the horizontal test sweep in its strongest wind, every cell flown
    eagerly (compiling six envs would cost minutes; the physics is the same)."""
    patch = pytest.MonkeyPatch()
    patch.setattr(ablation, "policy_compile_step", lambda payload: False)
    scenarios, quick = sweep_setup(SWEEPS[REGIME], quick=True)
    scenarios = scenarios[scenarios["wind_speed_ref_m_s"] == scenarios["wind_speed_ref_m_s"].max()][:3]
    estimator = load_estimator(REGIME)
    result = headroom(REGIME, scenarios, POLICY, estimator, config_override=quick)
    dob = ablation.fly_controllers(REGIME, scenarios, POLICY, estimator, ("dob",), config_override=quick)["dob"]
    yield result, dob
    patch.undo()


def test_the_full_wind_cell_is_the_ablations_observer(flown):
    """Flown in the error budget's PD slot, the base is bit for bit the ablation's ``dob`` row."""
    result, dob = flown
    cell = result["cells"]["navigation"]["full"]
    for axis in AXES:
        assert cell[f"rmse_{axis}"] == getattr(dob, f"rmse_{axis}").double().mean().item()
    assert result["base"] == "dob" and result["law"]["disturbance"] == "observer"


def test_the_decomposition_is_consistent(flown):
    result, _ = flown
    cells = result["cells"]
    assert result["episodes"] == 3 and set(cells) == {"navigation", "true_state"}
    for sensing in cells.values():
        assert set(sensing) == {"full", "mean_only", "still"}
        assert all(c["crashed"] == 0 for c in sensing.values())
    for axis in AXES:
        nav, true = cells["navigation"], cells["true_state"]
        # on the true state the base flies what it is scored on: no navigation error
        assert all(c[f"nav_rmse_{axis}"] == 0.0 for c in true.values())
        assert nav["full"][f"nav_rmse_{axis}"] > 0.0
        # still air on the truth is the easiest flight; on the truth the wind adds error, and the
        # sensing adds error in full wind. (Under the navigation error the wind need not add any
        # on a few episodes: these short flights' biases are larger than their wind error.)
        assert true["still"][f"rmse_{axis}"] < nav["full"][f"rmse_{axis}"]
        assert true["full"][f"rmse_{axis}"] > true["still"][f"rmse_{axis}"]
        assert nav["full"][f"rmse_{axis}"] > true["full"][f"rmse_{axis}"]
        s = result["split"][axis]
        assert s["total"] == nav["full"][f"rmse_{axis}"]
        for order in ("wind_on_true_state", "sensing_in_still_air"):
            parts = s[order]
            assert set(parts) == {"still_air_true_state", "mean_wind", "turbulence", "sensing"}
            assert sum(p["rmse"] for p in parts.values()) == pytest.approx(s["total"], rel=1e-12)
            assert sum(p["share_pct"] for p in parts.values()) == pytest.approx(100.0, rel=1e-12)
            assert parts["still_air_true_state"]["rmse"] > 0.0
        assert s["headroom_pct"] == pytest.approx(100.0 * (1.0 - s["navigation_error"] / s["total"]))


def test_without_mean_only_the_wind_is_one_part(flown):
    result, _ = flown
    cells = {sensing: {w: c for w, c in by_wind.items() if w != "mean_only"} for sensing, by_wind in result["cells"].items()}
    parts = split(cells, "xy")["wind_on_true_state"]
    assert set(parts) == {"still_air_true_state", "wind", "sensing"}
    assert parts["wind"]["rmse"] == pytest.approx(
        cells["true_state"]["full"]["rmse_xy"] - cells["true_state"]["still"]["rmse_xy"])


def test_the_section_renders_what_the_file_holds(flown, tmp_path):
    result, _ = flown
    saved = dict(result, sweep=REGIME, command="python recipes/headroom.py", git_commit="abc123")
    (tmp_path / "headroom_horizontal.json").write_text(json.dumps(saved))
    text = SECTION.render(ReportContext(tmp_path, tmp_path))
    assert text.startswith("## Headroom over the best classical controller")
    assert "`python recipes/headroom.py` at `abc123`" in text
    assert f"{result['cells']['navigation']['full']['rmse_xy']:.3f}" in text
    assert f"{result['split']['z']['headroom_pct']:.0f} %" in text
    # the parts in the order the split takes them, not the file's sorted keys
    assert text.index("| still air, true state") < text.index("| mean wind |") < text.index("| navigation (sensing) |")
    assert SECTION.render(ReportContext(tmp_path / "nothing_here", tmp_path)) is None
    # another base's file, where the recipe's --results put it: a row and a block of its own, after the observer's
    other = tmp_path / "experiments" / "headroom_dob_inner"
    other.mkdir(parents=True)
    (other / "headroom_horizontal.json").write_text(json.dumps(dict(saved, base="dob_inner", git_commit="def456")))
    text = SECTION.render(ReportContext(tmp_path, tmp_path))
    assert text.index("| horizontal | `dob` |") < text.index("| horizontal | `dob_inner` |")
    assert text.index("**horizontal, `dob`** (`results/headroom_horizontal.json`") < text.index(
        "**horizontal, `dob_inner`** (`results/experiments/headroom_dob_inner/headroom_horizontal.json`")
    assert "at `def456`" in text


def test_bad_input_is_refused():
    scenarios = SWEEPS[REGIME].scenarios()[:1]
    with pytest.raises(ValueError, match="base='pd_ff'"):
        headroom(REGIME, scenarios, POLICY, None, base="pd_ff")
    with pytest.raises(ValueError, match="needs \\['still'\\]"):
        headroom(REGIME, scenarios, POLICY, None, winds=("full", "mean_only"))
    with pytest.raises(ValueError, match="axis='x'"):
        split({}, "x")
