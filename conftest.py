"""Repository-wide pytest hooks (loaded for every run from the repository root)."""
import pytest


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    # pytest exits 5 when it collected nothing: for CI that is a broken suite, never a pass
    if exitstatus == pytest.ExitCode.NO_TESTS_COLLECTED:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config, items: list[pytest.Item]) -> None:
    # the longest tests first: pytest-xdist hands tests out in collection order, and a minutes-long
    # test collected last (tests/test_reproduce.py sorts late) runs alone at the end while the other
    # worker idles, adding its whole length to the suite's wall time
    items.sort(key=lambda item: item.get_closest_marker("long") is None)
