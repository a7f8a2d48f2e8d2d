"""Two processes on this machine, joined by jax.distributed (CPU collectives: gloo),
fit their own shares of a batch over one mesh of both processes' devices; together
they give what one process gives with as many devices (jaxpose.parallel.fit_batch,
jaxpose.distributed).

Each process has one CPU device; process 0 fits images 0 and 2, process 1 image 1
(the round-robin share), so process 1 pads its share to two: the per-device
program is the one of the single process with two forced devices (two images per
device), and the results must agree image by image.
"""

from __future__ import annotations

import socket
import subprocess
import sys

import numpy as np
import pytest
from test_sharding import WORKER, assert_same_fits, fits, forced_devices_env

from jaxpose.distributed import share


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def test_share_is_round_robin():
    items = list(range(7))
    shares = [share(items, i, 3) for i in range(3)]
    assert shares == [[0, 3, 6], [1, 4], [2, 5]]
    assert sorted(i for sh in shares for i in sh) == items


def test_two_processes_equal_one_process(tmp_path, two_devices):
    port = free_port()
    procs, outs = [], []
    for pid in range(2):
        out = tmp_path / f"p{pid}.npz"
        images = [str(i) for i in share(range(3), pid, 2)]
        env = forced_devices_env(1)
        env.update(JAXPOSE_DISTRIBUTED="1", JAX_COORDINATOR_ADDRESS=f"localhost:{port}", JAX_NUM_PROCESSES="2",
                   JAX_PROCESS_ID=str(pid))
        procs.append(subprocess.Popen([sys.executable, WORKER, str(out), "--mesh", "1", "--images", *images],
                                      env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
        outs.append(out)
    try:
        for p in procs:
            _, err = p.communicate(timeout=300)
            assert p.returncode == 0, err[-3000:]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    parts = [dict(np.load(o)) for o in outs]
    assert [p["processes"] for p in parts] == [2, 2] and [p["devices"] for p in parts] == [2, 2]
    # the mesh of "1 device per process" spans both processes: two devices in all
    order = [0, 2, 1]  # process 0 holds images 0 and 2, process 1 image 1
    joined = [np.concatenate([parts[0][k], parts[1][k]])[np.argsort(order)] for k in ("cost_1", "genome_1", "ends_1")]
    assert_same_fits(joined, fits(two_devices, 2), cost_rtol=1e-6, genome_atol=1e-6, ends_atol=1e-6)


@pytest.mark.parametrize("bad, match", [
    ({"coordinator": "localhost"}, "HOST:PORT"),
    ({"coordinator": "localhost:0x"}, "HOST:PORT"),
    ({"num_processes": 0}, "num_processes must be >= 1"),
    ({"num_processes": 2, "process_id": 2}, "process_id must lie within"),
])
def test_bad_settings(bad, match):
    from jaxpose.distributed import settings
    from jaxpose.errors import ConfigError

    with pytest.raises(ConfigError, match=match):
        settings(**bad)


def test_a_bad_setting_in_the_environment_is_one_error_line(tmp_path):
    """JAXPOSE_DISTRIBUTED=1 joins the run at import; a bad setting there surfaces as the
    command's one-line error, not a traceback at import."""
    env = forced_devices_env(1)
    env.update(JAXPOSE_DISTRIBUTED="1", JAX_COORDINATOR_ADDRESS="nohost", JAX_NUM_PROCESSES="2", JAX_PROCESS_ID="0")
    proc = subprocess.run([sys.executable, "-m", "jaxpose.cli", "fit", str(tmp_path / "a.npy"), "--skeleton", "spider",
                           "--out", str(tmp_path / "a.json")], env=env, capture_output=True, text=True, timeout=120,
                          check=False)
    assert proc.returncode == 2
    assert proc.stderr == ("jaxpose: error: JAXPOSE_DISTRIBUTED=1: coordinator 'nohost': give HOST:PORT "
                           "(e.g. node0:8476)\n")
    assert not (tmp_path / "a.json").exists()
