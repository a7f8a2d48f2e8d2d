"""The suite compiles with XLA's quickest settings (tests/xla_settings.py, applied by
tests/conftest.py).  Oracle: the same computation in a fresh interpreter with XLA's
defaults, as users run it; the search's cost and gradient agree to float32 round-off."""

import os
import subprocess
import sys

import numpy as np
from xla_probe import probe
from xla_settings import _name, quick_options, with_quick, without_quick

PROBE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "xla_probe.py")


def test_the_suite_runs_with_the_quick_settings_unless_asked_not_to(monkeypatch):
    names = {_name(f) for f in os.environ.get("XLA_FLAGS", "").split()}
    default = os.environ.get("JAXPOSE_TEST_XLA", "").strip().lower() == "default"
    assert default or all(_name(q) in names for q in quick_options())  # set, by the suite (or by the user)
    monkeypatch.delenv("JAXPOSE_TEST_XLA", raising=False)
    assert with_quick("").split() == quick_options()
    mine = "--xla_backend_optimization_level=2 --xla_force_host_platform_device_count=2"
    assert with_quick(mine).split()[:2] == mine.split()  # a user's own value is kept, not doubled
    assert [_name(f) for f in with_quick(mine).split()].count("--xla_backend_optimization_level") == 1
    assert without_quick(mine) == "--xla_force_host_platform_device_count=2"
    monkeypatch.setenv("JAXPOSE_TEST_XLA", "default")
    assert with_quick(mine) == mine


def test_quick_settings_change_cost_and_gradient_by_round_off_only(tmp_path):
    out = tmp_path / "defaults.npz"
    env = dict(os.environ, XLA_FLAGS=without_quick(os.environ.get("XLA_FLAGS", "")))
    proc = subprocess.run([sys.executable, PROBE, str(out)], env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    want, got = dict(np.load(out)), probe()
    assert np.all(np.isfinite(want["cost"])) and np.ptp(want["cost"]) > 0.01  # poses that cost differently
    np.testing.assert_allclose(got["cost"], want["cost"], rtol=1e-5, atol=0)
    for name in ("grad_angles", "grad_root_t"):
        assert np.abs(want[name]).max() > 1e-3, name  # a gradient that is not zero
        np.testing.assert_allclose(got[name], want[name], rtol=1e-4, atol=1e-5 * np.abs(want[name]).max())
