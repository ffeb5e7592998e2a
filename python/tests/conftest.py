"""The order the test files start in on xdist's workers (`--dist loadfile`: each file whole on
one worker, in this order, `--no-loadscope-reorder` keeping it): the longest first, so that no
worker is left with a long file while the others are done. Measured on a 2-core machine in a
whole run (minutes): the position flights 12.5, the five-minute dive 5.2, the fit 5.0, the page
3.5, the firmware's faults 3.3; every other file under 2."""

LONGEST_FIRST = ["test_ardusub_position.py", "test_long_dive.py", "test_ardusub_fit.py", "test_serve_page.py",
                 "test_ardusub_sitl.py"]


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    # A stable sort: within a file, and among the other files, the collected order stays.
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
