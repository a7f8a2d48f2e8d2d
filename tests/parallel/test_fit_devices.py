"""``jaxpose fit`` on several inputs over several devices (--devices, --batch, --resume):
the results of two devices are those of one, --resume skips what is written, bad
options end with one line.  The command runs in a subprocess with two forced host
devices (XLA_FLAGS is read when JAX starts), every run in that one process so that
the batch compiles once per device count."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from test_sharding import forced_devices_env

DRIVER = r"""
import contextlib, io, json, os, sys
import jaxpose
from jaxpose.cli import main

d = sys.argv[1]
tiny = ["--skeleton", "spider", "--population", "8", "--generations", "4", "--islands", "2", "--no-refine",
        "--turns", "0", "--limb-sweep", "0", "--pivot-sweep", "0", "--max-points", "128"]
log = {}
for s in (1, 2, 3):
    assert main(["render", "--skeleton", "spider", "--size", "160x120", "--seed", str(s), "--out", f"{d}/d{s}.png",
                 "--truth", f"{d}/t{s}.json"]) == 0
inputs = [f"{d}/d{s}.png" for s in (1, 2, 3)] + ["--intrinsics", f"{d}/t1.json"]

def run(name, *argv, inputs=inputs):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(["fit", *inputs, *tiny, *argv])
    log[name] = {"rc": rc, "out": out.getvalue(), "err": err.getvalue()}

for n in ("all", "one", "resume"):
    os.makedirs(f"{d}/{n}")
run("all", "--out-dir", f"{d}/all", "--batch", "1")  # batches of 2 and 1 images: one program
run("one", "--out-dir", f"{d}/one", "--devices", "1", "--batch", "2")
run("resume_nothing", "--out-dir", f"{d}/all", "--resume")
os.remove(f"{d}/all/d2.json")
run("resume_one", "--out-dir", f"{d}/all", "--resume")
run("too_many", "--out-dir", f"{d}/one", "--devices", "3")
run("resume_no_dir", "--out", f"{d}/x.json", "--resume", inputs=inputs[:1] + inputs[3:])
run("devices_hypotheses", "--out-dir", f"{d}/one", "--devices", "2", "--hypotheses", "2")
one = inputs[:1] + inputs[3:]  # one input: its two islands over two devices, and over one
import jaxpose.parallel as par
real_islands = par.fit_islands

def spy(cloud, skel, key, config, mesh=None, params=None, progress=None):  # what the command ran
    seen = []
    def report(*p):
        seen.append(list(p))
        if progress is not None:
            progress(*p)
    r = real_islands(cloud, skel, key, config, mesh, params, report)
    log.setdefault("islands_calls", []).append({"devices": int(mesh.devices.size), "progress": seen,
                                                "generations": config.generations * config.searches})
    return r

par.fit_islands = spy
run("islands2", "--out", f"{d}/isl2.json", "--devices", "2", inputs=one)
run("islands1", "--out", f"{d}/isl1.json", "--devices", "1", inputs=one)
run("islands_odd", "--out", f"{d}/x.json", "--devices", "2", "--islands", "3", inputs=one)
run("islands_budget", "--out", f"{d}/x.json", "--devices", "2", "--time-budget", "5", inputs=one)
json.dump(log, open(f"{d}/log.json", "w"))
"""


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("devices")
    proc = subprocess.run([sys.executable, "-c", DRIVER, str(d)], env=forced_devices_env(2), capture_output=True,
                          text=True, timeout=600, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return d, json.loads((d / "log.json").read_text())


def result(d, folder, s):
    return json.loads((d / folder / f"d{s}.json").read_text())


def test_two_devices_give_the_results_of_one(runs):
    d, log = runs
    assert log["all"]["rc"] == 0 and log["one"]["rc"] == 0
    assert "on 2 CPU device(s)" in log["all"]["out"] and "on 1 CPU device(s)" in log["one"]["out"]
    assert "batch 2/2: 1 images" in log["one"]["out"]  # --batch 2 on one device: batches of 2 and 1
    assert "batch 2/2: 1 images" in log["all"]["out"]  # --batch 1 on two devices: the same
    costs = []
    for s in (1, 2, 3):
        a, b = result(d, "all", s), result(d, "one", s)
        assert a["input"] == b["input"] and a["config"] == b["config"]
        np.testing.assert_allclose(a["cost"], b["cost"], rtol=1e-6)
        ends = lambda doc: np.array([link["end"] for link in doc["links"]])  # noqa: E731
        np.testing.assert_allclose(ends(a), ends(b), atol=1e-5)
        assert a["timing"]["batch"]["devices"] == 2 and b["timing"]["batch"]["devices"] == 1
        costs.append(a["cost"])
    assert len({round(c, 4) for c in costs}) == 3  # three different images: an order mix-up would show


def test_resume_skips_what_is_written(runs):
    d, log = runs
    nothing = log["resume_nothing"]
    assert nothing["rc"] == 0 and "3 of 3 results already written, skipped" in nothing["out"]
    assert "batch" not in log["resume_nothing"]["out"].split("skipped", 1)[1].replace("images per batch", "")
    assert log["resume_one"]["rc"] == 0 and "2 of 3 results already written" in log["resume_one"]["out"]
    assert "d2.png: cost" in log["resume_one"]["out"] and "d1.png: cost" not in log["resume_one"]["out"]
    np.testing.assert_allclose(result(d, "all", 2)["cost"], result(d, "one", 2)["cost"], rtol=1e-6)


@pytest.mark.parametrize("name, message", [
    ("too_many", "jaxpose: error: --devices must lie within 1 .. 2 (this machine's CPU devices), got 3"),
    ("resume_no_dir", "jaxpose: error: --resume works with --out-dir"),
    ("devices_hypotheses", "jaxpose: error: --hypotheses fits one input at a time, on one device: not with --devices"),
    ("islands_odd", "jaxpose: error: --devices 2: one input's 3 islands do not split evenly over 2 devices"),
    ("islands_budget", "jaxpose: error: --time-budget fits one input at a time, on one device: not with --devices"),
])
def test_bad_options(runs, name, message):
    _, log = runs
    assert log[name]["rc"] == 2 and log[name]["err"].startswith(message) and log[name]["err"].count("\n") == 1
    assert log[name]["out"] == ""


def test_one_input_splits_its_islands_over_the_devices(runs):
    """``--devices N`` on one input: the fit's islands split over N devices
    (jaxpose.parallel.fit_islands); two devices give what one gives."""
    d, log = runs
    assert log["islands2"]["rc"] == 0 and log["islands1"]["rc"] == 0, log["islands2"]["err"] + log["islands1"]["err"]
    assert log["islands2"]["out"].startswith("spider: cost ") and log["islands2"]["out"].count("\n") == 1
    a, b = (json.loads((d / f"isl{n}.json").read_text()) for n in (2, 1))
    assert a["timing"]["devices"] == 2 and b["timing"]["devices"] == 1 and a["config"] == b["config"]
    np.testing.assert_allclose(a["cost"], b["cost"], rtol=1e-6)
    ends = lambda doc: np.array([link["end"] for link in doc["links"]])  # noqa: E731
    np.testing.assert_allclose(ends(a), ends(b), atol=1e-5)
    assert a["evaluations"]["objective"] == b["evaluations"]["objective"] > 0
    calls = log["islands_calls"]  # fit_islands ran, on a mesh of two devices, then of one
    assert [c["devices"] for c in calls] == [2, 1]
    for c, doc in zip(calls, (a, b)):  # progress after each search, up to the whole fit's generations and counts
        gens, best, evals = zip(*c["progress"])
        assert len(gens) > 1 and list(gens) == sorted(gens) and gens[-1] == c["generations"]
        assert np.isclose(best[-1], doc["cost"], rtol=1e-6)  # the cheapest search's cost is the answer's
        assert evals[-1] == doc["evaluations"]["objective"] + doc["evaluations"]["gradient"]
    assert not (d / "x.json").exists()  # the refused runs wrote nothing
