"""The suite runs on two workers (python/pyproject.toml: `-n 2 --dist loadgroup`). Each test
file is one group, so its module-scoped fixtures (whole batches of firmware flights) run once,
on one worker. The files whose batches load the CPU most (up to eight simulators and closed
loops at once, measured load 1.7 of 2 cores) share one group, so they never fly at the same
time as each other; a lighter file flies beside them."""

import pytest

HEAVY = {"test_ardusub_position", "test_ardusub_fit"}


def pytest_collection_modifyitems(items):
    for item in items:
        module = item.module.__name__.rsplit(".", 1)[-1]
        item.add_marker(pytest.mark.xdist_group("heavy" if module in HEAVY else module))
