"""``python -m jaxpose.demo`` (``make demo``): fit the bundled spider image, write
``result.json`` (+ ``overlay.png`` with matplotlib) and print the accuracy.

The demo has no option for the search budget (the default ``FitConfig``: minutes
on a laptop), so the fast test runs the demo's own ``main`` with the fit command
given a tiny budget: the last occurrence of a flag wins with argparse, so the
budget flags are appended to whatever the demo passes.  The unmodified demo runs
in the ``slow`` test.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import math
import os
import subprocess
import sys

import pytest

import jaxpose.cli
from jaxpose import demo

DATA = os.path.join(os.path.dirname(os.path.abspath(demo.__file__)), "data")
HAS_MPL = importlib.util.find_spec("matplotlib") is not None

# the same small fit as tests/commands/test_cli.py (one compilation per session for both files)
TINY = ["--population", "32", "--generations", "10", "--islands", "1", "--no-refine", "--turns", "0",
        "--limb-sweep", "0", "--pivot-sweep", "0", "--free-space-weight", "0", "--max-points", "256"]

# README, section "result.json"
DOCUMENTED = {
    "schema", "skeleton", "input", "algorithm", "config", "seed", "frame", "links", "params", "genome",
    "cost", "cost_history", "evaluations", "versions", "timing",
}


def _sha256(path):
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


def check_result(out_dir, seed, population, generations):
    doc = json.loads((out_dir / "result.json").read_text())
    assert set(doc) >= DOCUMENTED, DOCUMENTED - set(doc)
    assert doc["schema"] == 1 and doc["seed"] == seed and doc["algorithm"] == "ga"
    assert doc["frame"] == "camera (x right, y down, z forward), metres"
    assert {"name", "file", "sha256", "num_links", "dof"} <= set(doc["skeleton"])
    assert doc["skeleton"]["name"] == "spider"
    inp = doc["input"]
    assert inp["depth"] == "spider_demo.png" and inp["depth_sha256"] == _sha256(os.path.join(DATA, "spider_demo.png"))
    assert inp["background"] == "spider_demo_background.png"
    assert inp["background_sha256"] == _sha256(os.path.join(DATA, "spider_demo_background.png"))
    k = inp["intrinsics"]  # the default: Kinect v1
    assert (k["fx"], k["fy"], k["cx"], k["cy"], k["width"], k["height"]) == (525, 525, 319.5, 239.5, 640, 480)
    for key in ("depth_scale", "near", "far", "max_points", "points_used", "sample_seed"):
        assert key in inp
    assert 0 < inp["points_used"] <= inp["max_points"]
    cfg = doc["config"]
    assert (cfg["population"], cfg["generations"]) == (population, generations)
    truth = json.loads(open(os.path.join(DATA, "spider_demo_truth.json")).read())
    assert [link["name"] for link in doc["links"]] == [link["name"] for link in truth["links"]]
    for link in doc["links"]:
        assert {"name", "parent", "origin", "start", "end", "radius"} <= set(link)
        assert len(link["origin"]) == len(link["start"]) == len(link["end"]) == 3
        assert all(math.isfinite(v) for v in link["origin"] + link["start"] + link["end"])
    assert {"root_translation", "root_rpy", "scale", "joints", "lengths"} <= set(doc["params"])
    assert len(doc["genome"]) == doc["skeleton"]["dof"]
    assert math.isfinite(doc["cost"]) and len(doc["cost_history"]) == generations
    assert doc["cost"] <= min(doc["cost_history"]) + 1e-9
    assert set(doc["evaluations"]) == {"objective", "gradient", "point_to_capsule_distances"}
    assert {"python", "jaxpose", "jax", "jaxlib", "evosax", "optax", "numpy", "imageio"} <= set(doc["versions"])
    assert doc["timing"]["wall_seconds"] > 0
    plot = out_dir / "overlay.png"
    if HAS_MPL:
        assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    else:
        assert not plot.exists()
    return doc


def test_demo_with_a_tiny_budget(tmp_path, monkeypatch, capsys):
    real = jaxpose.cli.main
    calls = []

    def tiny(argv):
        argv = list(argv)
        calls.append(argv[0])
        return real(argv + TINY if argv[0] == "fit" else argv)

    monkeypatch.setattr(jaxpose.cli, "main", tiny)
    out = tmp_path / "demo"  # created by the demo
    rc = demo.main(["--out", str(out), "--seed", "5", "--quiet"])
    stdout, stderr = capsys.readouterr()
    assert rc == 0, stderr
    assert calls == ["fit", "eval"]
    check_result(out, seed=5, population=32, generations=10)
    assert "accuracy against the bundled ground truth" in stdout
    assert "links correct (PCP, half true length)" in stdout and "mean end point error (MPJPE, mm)" in stdout
    assert "spider: 8 links, 24 symmetries" in stdout  # eval's header (docs/data.md: spider 4! = 24)


@pytest.mark.slow
def test_demo_as_shipped(tmp_path):
    out = tmp_path / "demo"
    p = subprocess.run([sys.executable, "-m", "jaxpose.demo", "--out", str(out), "--quiet"],
                       capture_output=True, text=True, timeout=3600)
    assert p.returncode == 0, p.stderr
    from jaxpose import load_skeleton
    from jaxpose.search import FitConfig, auto_generations

    # the default generations, chosen for the spider (4 per gene: 156)
    check_result(out, seed=0, population=FitConfig.population, generations=auto_generations(load_skeleton("spider")))
    assert "accuracy against the bundled ground truth" in p.stdout
