"""What the tests of several devices share: the fits of one batch on one and two forced host devices."""

import pytest
from test_sharding import run_worker


@pytest.fixture(scope="session")
def two_devices(tmp_path_factory):
    """Probe clouds 0..2 fitted on one and on two devices, one by one by the unsharded fit,
    and the first with its two islands split over two devices."""
    return run_worker(tmp_path_factory.mktemp("sharding"), "two", "--mesh", "1", "2", "--single", "--islands")
