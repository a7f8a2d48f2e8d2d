"""Test-wide settings.  The tests mirror the package (tests/io/ for jaxpose/io/, ...);
wherever they lie they import tests/oracles.py and read tests/fixtures/."""

import os
import sys

TESTS = os.path.dirname(os.path.abspath(__file__))
if TESTS not in sys.path:  # `import oracles` from every subfolder
    sys.path.insert(0, TESTS)

# The command line keeps compiled programs on disk between runs; tests must not
# depend on (or fill) a user's cache, so it is off here.  tests/commands/test_cli.py turns
# it on explicitly where it is tested.
os.environ["JAXPOSE_CACHE_DIR"] = "0"
# MuJoCo picks its OpenGL platform when it is imported; tests/experiments/test_mujoco_views.py renders
# off screen (headless EGL), so ask for that before any test imports mujoco.
if sys.platform.startswith("linux"):  # MuJoCo refuses MUJOCO_GL=egl (at import) elsewhere
    os.environ.setdefault("MUJOCO_GL", "egl")

# XLA reads XLA_FLAGS when JAX starts its backend (after this file runs); subprocesses inherit it.
# The suite compiles with XLA's quickest settings (tests/xla_settings.py; JAXPOSE_TEST_XLA=default: XLA's own).
from xla_settings import with_quick  # noqa: E402

os.environ["XLA_FLAGS"] = with_quick(os.environ.get("XLA_FLAGS", ""))


import pytest  # noqa: E402


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A 160x120 depth PNG of the spider in a random pose, its truth file and its intrinsics."""
    from jaxpose.cli import main

    d = tmp_path_factory.mktemp("scene")
    rc = main(["render", "--skeleton", "spider", "--size", "160x120", "--seed", "3",
               "--out", str(d / "depth.png"), "--truth", str(d / "truth.json")])
    assert rc == 0
    return d
