"""Robot model files end to end through the command line: ``render`` -> ``fit`` -> ``eval``.

The link names and parents are read from the files independently (the URDF with
``xml.etree``, the MJCF with MuJoCo's own compiler; an unnamed body is
``body<id>`` as documented in ``jaxpose/io/mjcf.py``), and the metrics that
``eval --json`` reports are recomputed in NumPy from the two JSON files.
Fits are tiny (16 individuals, 10 generations, one island, no refinement); each
still compiles its skeleton's search for about 20-30 s, so the MJCF ant (a second
skeleton, a second compilation) is marked ``slow`` to keep this file under a minute:
run it with ``pytest -m slow tests/test_robot_end_to_end.py``.
"""

from __future__ import annotations

import json
import math
import os
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from jaxpose.cli import main
from jaxpose.io.capsules import EXTRA_CAPSULE, MAX_CAPSULES

FIXTURES = os.path.join(os.path.dirname(os.path.abspath(__file__)), "fixtures")
TINY = ["--population", "16", "--generations", "10", "--islands", "1", "--no-refine", "--turns", "0",
        "--limb-sweep", "0", "--pivot-sweep", "0", "--max-points", "256", "--quiet"]


def urdf_tree(path):
    """``{link name: parent link name or None}`` of a URDF file."""
    root = ET.parse(path).getroot()
    links = {link.get("name"): None for link in root.findall("link")}
    for joint in root.findall("joint"):
        links[joint.find("child").get("link")] = joint.find("parent").get("link")
    return links


def mjcf_tree(path):
    """``{body name: parent body name or None}`` of an MJCF file, world body excluded."""
    mujoco = pytest.importorskip("mujoco")
    m = mujoco.MjModel.from_xml_path(path)
    name = lambda i: m.body(i).name or f"body{i}"  # noqa: E731
    return {name(i): (name(int(m.body_parentid[i])) if m.body_parentid[i] != 0 else None)
            for i in range(1, m.nbody)}


def metrics_oracle(result, truth):
    """Strict PCP (both ends within half the true length; links of zero true length, a sphere or a
    fixed frame, are not scored: jaxpose.metrics.pcp_scored), PCP@10cm, PCK@10cm, MPJPE (mm), by name."""
    t = {link["name"]: link for link in truth["links"]}
    ps, pe, ts, te = (np.array([link[k] for link in result["links"]], float) if src == "r" else
                      np.array([t[link["name"]][k] for link in result["links"]], float)
                      for src, k in (("r", "start"), ("r", "end"), ("t", "start"), ("t", "end")))
    ds = np.linalg.norm(ps - ts, axis=1)
    de = np.linalg.norm(pe - te, axis=1)
    half = 0.5 * np.linalg.norm(te - ts, axis=1)
    both = np.concatenate([ds, de])
    return {
        "pcp": float(np.mean(((ds <= half) & (de <= half))[half > 0])),
        "pcp_10cm": float(np.mean((ds <= 0.1) & (de <= 0.1))),
        "pck_10cm": float(np.mean(both <= 0.1)),
        "mpjpe_mm": float(1000 * both.mean()),
    }


def end_to_end(tmp_path, capsys, skeleton, tree, render_extra=()):
    a, t, r = tmp_path / "a.png", tmp_path / "t.json", tmp_path / "r.json"
    assert main(["render", "--skeleton", skeleton, "--size", "160x120", "--seed", "1", *render_extra,
                 "--out", str(a), "--truth", str(t)]) == 0
    assert main(["fit", str(a), "--skeleton", skeleton, "--intrinsics", str(t), "--seed", "2",
                 "--out", str(r), *TINY]) == 0
    capsys.readouterr()
    result, truth = json.loads(r.read_text()), json.loads(t.read_text())

    # every link of the file, by name, with its parent, in the file's tree; a link's extra capsules
    # (several capsules per link, the default for robot files) are fixed links under it
    extras = {link["name"]: link["parent"] for link in result["links"] if EXTRA_CAPSULE in link["name"]}
    for name, parent in extras.items():
        assert parent in tree and name.startswith(parent + EXTRA_CAPSULE), name
    tree = {**tree, **extras}
    names = [link["name"] for link in result["links"]]
    assert sorted(names) == sorted(tree) and len(set(names)) == len(names)
    for link in result["links"]:
        assert link["parent"] == tree[link["name"]], link["name"]
        for key in ("origin", "start", "end"):
            assert len(link[key]) == 3 and all(math.isfinite(v) for v in link[key]), (link["name"], key)
        assert math.isfinite(link["radius"]) and link["radius"] >= 0
    assert result["skeleton"]["num_links"] == len(tree)
    assert result["skeleton"]["max_capsules"] == MAX_CAPSULES  # the default for robot files
    # a robot file has its robot's size: the scale is held at 1 unless --search-scale
    assert result["skeleton"]["search_scale"] is False and result["params"]["scale"] == 1.0
    assert sorted(link["name"] for link in truth["links"]) == sorted(tree)
    assert truth["camera"]["intrinsics"]["width"] == 160 and truth["camera"]["intrinsics"]["height"] == 120

    # eval: the documented fields, and the strict numbers recomputed from the files
    assert main(["eval", str(r), str(t), "--json"]) == 0
    stdout, stderr = capsys.readouterr()
    m = json.loads(stdout)
    assert stderr == ""  # the truth names its skeleton file, so eval finds it
    assert m["num_links"] == len(tree) and m["symmetries"] >= 1
    assert m["result"] == str(r) and m["truth"] == str(t)
    assert set(m["per_link"]) == set(tree) and set(m["matching"]) == set(tree)
    oracle = metrics_oracle(result, truth)
    for kind in ("strict", "symmetric"):
        assert set(m[kind]) >= {"pcp", "pcp_10cm", "pck_10cm", "mpjpe_mm"}
    for key, value in oracle.items():
        assert m["strict"][key] == pytest.approx(value, rel=1e-9, abs=1e-9), key
    assert m["symmetric"]["mpjpe_mm"] <= m["strict"]["mpjpe_mm"] + 1e-9
    assert m["symmetric"]["pcp"] >= m["strict"]["pcp"] - 1e-12
    for name, row in m["per_link"].items():
        tl = next(link for link in truth["links"] if link["name"] == name)
        rl = next(link for link in result["links"] if link["name"] == name)
        assert row["start_error_mm"] == pytest.approx(1000 * math.dist(rl["start"], tl["start"]), rel=1e-9, abs=1e-9)
        assert row["end_error_mm"] == pytest.approx(1000 * math.dist(rl["end"], tl["end"]), rel=1e-9, abs=1e-9)
    # the truth against itself is perfect
    assert main(["eval", str(t), str(t), "--json"]) == 0
    perfect = json.loads(capsys.readouterr().out)
    assert perfect["strict"]["mpjpe_mm"] == 0.0 and perfect["strict"]["pck_10cm"] == 1.0


def test_urdf_arm_end_to_end(tmp_path, capsys):
    path = os.path.join(FIXTURES, "arm7.urdf")
    tree = urdf_tree(path)
    assert len(tree) == 8  # the fixture itself
    end_to_end(tmp_path, capsys, path, tree)


@pytest.mark.slow
def test_mjcf_ant_end_to_end(tmp_path, capsys):
    path = os.path.join(FIXTURES, "ant.xml")
    tree = mjcf_tree(path)  # skips without mujoco
    assert len(tree) == 13
    end_to_end(tmp_path, capsys, path, tree, render_extra=("--distance", "2.5", "--elevation", "40"))


def test_search_lengths_flag(tmp_path, capsys):
    """--search-lengths reaches the importer; on a native file it is one clear error before any search."""
    npy = tmp_path / "d.npy"
    np.save(npy, np.full((120, 160), 1.5, np.float32))
    assert main(["fit", str(npy), "--skeleton", "spider", "--search-lengths", "--out", str(tmp_path / "r.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--search-lengths: only for robot files" in err[0], err
    assert not (tmp_path / "r.json").exists()


@pytest.mark.parametrize("extra, words", [(["--search-scale"], "--search-scale: only for robot files"),
                                          (["--search-scale", "--scale", "1", "--skeleton", "arm7.urdf"],
                                           "--search-scale and --scale 1: give one")])
def test_search_scale_flag_errors(tmp_path, capsys, extra, words):
    """--search-scale on a native file, or with --scale: one clear error before any search, no output."""
    npy = tmp_path / "d.npy"
    np.save(npy, np.full((120, 160), 1.5, np.float32))
    out = tmp_path / "r.json"
    extra = [os.path.join(FIXTURES, e) if e.endswith(".urdf") else e for e in extra]
    assert main(["fit", str(npy), "--skeleton", "spider", *extra, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
    assert not out.exists()


@pytest.mark.parametrize("value, words", [("2", "--max-capsules: only for robot files"),
                                          ("0", "--max-capsules: must be at least 1")])
def test_max_capsules_flag_errors(tmp_path, capsys, value, words):
    """--max-capsules on a native file, or below 1: one clear error before any search, no output."""
    npy = tmp_path / "d.npy"
    np.save(npy, np.full((120, 160), 1.5, np.float32))
    out = tmp_path / "r.json"
    skeleton = "spider" if value == "2" else os.path.join(FIXTURES, "arm7.urdf")
    assert main(["fit", str(npy), "--skeleton", skeleton, "--max-capsules", value, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
    assert not out.exists()


def test_max_capsules_flag_reaches_the_importer_and_the_record(tmp_path, capsys):
    """One capsule per link: the URDF's links exactly, recorded in result.json; such a result does
    not match a truth rendered with the default model (one clear error), and eval finds the default
    model's skeleton from a truth's link names."""
    path = os.path.join(FIXTURES, "gripper.urdf")
    a, t, r = tmp_path / "a.png", tmp_path / "t.json", tmp_path / "r.json"
    assert main(["render", "--skeleton", path, "--size", "160x120", "--seed", "1", "--out", str(a),
                 "--truth", str(t)]) == 0
    assert main(["fit", str(a), "--skeleton", path, "--intrinsics", str(t), "--max-capsules", "1",
                 "--search-scale", "--out", str(r), *TINY]) == 0
    capsys.readouterr()
    result = json.loads(r.read_text())
    assert result["skeleton"]["max_capsules"] == 1 and result["skeleton"]["search_scale"] is True
    assert 0.5 <= result["params"]["scale"] <= 2.0  # searched (SEARCHED_SCALE_RANGE)
    assert {link["name"]: link["parent"] for link in result["links"]} == urdf_tree(path)
    # the truth was rendered with the default model (extra capsules): a one-capsule result does not match it
    truth = json.loads(t.read_text())
    assert any(EXTRA_CAPSULE in link["name"] for link in truth["links"])
    assert main(["eval", str(r), str(t)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "links do not match" in err[0] and EXTRA_CAPSULE in err[0], err
    # the truth against itself: eval loads the skeleton with the extra capsules its names show
    assert main(["eval", str(t), str(t), "--json"]) == 0
    out, err = capsys.readouterr()
    assert err == "" and json.loads(out)["num_links"] == len(truth["links"])
    # rendered with one capsule per link too, the truth matches the result
    t1 = tmp_path / "t1.json"
    assert main(["render", "--skeleton", path, "--size", "160x120", "--seed", "1", "--max-capsules", "1",
                 "--out", str(tmp_path / "a1.png"), "--truth", str(t1)]) == 0
    assert {link["name"] for link in json.loads(t1.read_text())["links"]} == set(urdf_tree(path))
    capsys.readouterr()
    assert main(["eval", str(r), str(t1), "--json"]) == 0
    out, err = capsys.readouterr()
    assert err == "" and json.loads(out)["num_links"] == len(urdf_tree(path))


def test_skeleton_command_lists_the_extra_capsules(capsys):
    path = os.path.join(FIXTURES, "gripper.urdf")
    assert main(["skeleton", path]) == 0
    default = capsys.readouterr().out
    assert main(["skeleton", path, "--max-capsules", "1"]) == 0
    one = capsys.readouterr().out
    assert default.startswith("gripper: 7 links") and "turntable#capsule2" in default
    assert one.startswith("gripper: 6 links") and EXTRA_CAPSULE not in one
