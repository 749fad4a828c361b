"""The shared cells of the results page: number formats, interval cells and row orders that
more than one study's section prints (one home, so a figure reads the same everywhere)."""
from __future__ import annotations

import math


def by_number(table: dict) -> list[tuple[str, dict]]:
    """JSON object keys are strings: order wind levels numerically."""
    return sorted(table.items(), key=lambda kv: float(kv[0]))


def headroom_pct(nav_rmse: float, rmse: float) -> float:
    """``100 (1 - nav error / RMSE)``: about the largest improvement any controller could make
    (the navigation error is what the vehicle cannot see)."""
    return 100.0 * (1.0 - nav_rmse / rmse)


def wall_time(seconds: float) -> str:
    """Seconds under two minutes (a toy run is never "0 min"), minutes above."""
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.0f} min"


def ci(block: dict) -> str:
    """A paired bootstrap interval; "to", not a dash, since either end may be negative."""
    return f"{block['ci_low']:.1f} to {block['ci_high']:.1f}"


def spread(across: dict) -> str:
    """Seed mean (range) of an :func:`~quadwind_trl.evaluation.statistics.across_seeds` block."""
    return f"{across['mean']:+.1f} ({across['min']:+.1f} to {across['max']:+.1f})"


def t_cell(across: dict) -> str:
    """The 95 % t-interval over seeds of an ``across_seeds`` block; "-" with one seed."""
    if not math.isfinite(across["t_low"]):
        return "-"
    return f"{across['t_low']:+.1f} to {across['t_high']:+.1f}"


def seed_cells(block: dict | None) -> str:
    """Seed mean (range) and its 95 % t-interval with the seed count; "-" where no seed has it."""
    if block is None or block["across_seeds"]["n_seeds"] == 0:
        return "- | -"
    a = block["across_seeds"]
    return f"{spread(a)} | {t_cell(a)} ({a['n_seeds']})"


def paired_cell(block: dict | None) -> str:
    """A paired summary: improvement (bootstrap 95 % interval), wins."""
    return "-" if block is None else f"{block['improvement']:+.1f} ({ci(block)}), {block['wins']}/{block['n']}"


def seed_stats(values: list[float]) -> str:
    """Mean (range) of per-seed percentages."""
    return f"{sum(values) / len(values):+.1f} % ({min(values):+.1f} to {max(values):+.1f})"


SWEEP_TITLES = {"horizontal": "Horizontal", "vertical": "Vertical", "ood": "Out-of-distribution"}  # and their order on the page


def in_sweep_order(by_sweep: dict[str, dict]) -> list[tuple[str, dict]]:
    """A JSON object's sweeps (stored in key order) in the order of :data:`SWEEP_TITLES`."""
    return sorted(by_sweep.items(), key=lambda kv: list(SWEEP_TITLES).index(kv[0]) if kv[0] in SWEEP_TITLES else len(SWEEP_TITLES))


def wind_rows(by_wind: dict) -> list[tuple[str, dict]]:
    """Wind levels in numeric order, then ``"all"``."""
    return by_number({k: v for k, v in by_wind.items() if k != "all"}) + [("all", by_wind["all"])]


def present(by_wind: dict, names) -> list[str]:
    """The measures of ``names`` some wind group of an analysed sweep holds, in that order."""
    return [name for name in names if any(row.get(name) for row in by_wind.values())]
