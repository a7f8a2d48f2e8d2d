"""The ``jaxpose`` command end to end: render a small synthetic image, fit it, score it.

Fits are tiny (one island of 32 individuals, 10 generations, no gradient refinement, no
free-space term) and share one configuration, so that JAX compiles each
algorithm once per test session; compilation dominates their run time.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from jaxpose.cli import main
from jaxpose.io.depth_file import load_depth
from jaxpose.io.skeleton_file import load_skeleton

FIT = ["--skeleton", "spider", "--population", "32", "--generations", "10", "--islands", "1", "--quiet",
       "--no-refine", "--turns", "0", "--limb-sweep", "0", "--pivot-sweep", "0", "--free-space-weight", "0",
       "--max-points", "256"]


def _sha256(path) -> str:
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


def _run(capsys, *argv):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert rc == 0, err
    return out, err




@pytest.fixture(scope="module")
def ga_result(scene):
    out = scene / "result.json"
    rc = main(["fit", str(scene / "depth.png"), "--intrinsics", str(scene / "truth.json"), "--seed", "7",
               "--out", str(out)] + FIT)
    assert rc == 0
    return json.loads(out.read_text())


def test_render_wrote_a_16_bit_depth_image_and_truth(scene):
    depth = load_depth(scene / "depth.png")
    assert depth.shape == (120, 160) and np.isfinite(depth).sum() >= 50
    truth = json.loads((scene / "truth.json").read_text())
    assert truth["camera"]["intrinsics"]["width"] == 160 and len(truth["links"]) == 8


def test_result_json_schema(ga_result, scene):
    doc = ga_result
    skel = load_skeleton("spider")
    assert doc["schema"] == 1 and doc["algorithm"] == "ga" and doc["seed"] == 7
    assert "camera" in doc["frame"]
    # skeleton: name, file and its hash
    assert doc["skeleton"]["name"] == "spider" and doc["skeleton"]["num_links"] == 8
    assert doc["skeleton"]["dof"] == skel.num_dof == len(doc["genome"])
    assert doc["skeleton"]["sha256"] == _sha256(doc["skeleton"]["file"])
    # input: hashes and the settings that made the cloud
    inp = doc["input"]
    assert inp["depth"] == "depth.png" and inp["depth_sha256"] == _sha256(scene / "depth.png")
    assert inp["background"] is None and inp["background_sha256"] is None
    truth = json.loads((scene / "truth.json").read_text())
    assert inp["intrinsics"] == truth["camera"]["intrinsics"]
    assert inp["max_points"] == 256 and 50 <= inp["points_used"] <= 256
    # links by name, with parents, in the camera frame
    names = [link["name"] for link in doc["links"]]
    assert names == list(skel.link_names)
    by_name = {link["name"]: link for link in doc["links"]}
    for i, link in enumerate(doc["links"]):
        p = skel.parents[i]
        assert link["parent"] == (skel.link_names[p] if p >= 0 else None)
        assert len(link["start"]) == len(link["end"]) == len(link["origin"]) == 3
        assert all(math.isfinite(v) for v in link["start"] + link["end"]) and link["radius"] > 0
        if link["parent"]:  # a child starts where its parent ends
            assert np.allclose(link["start"], by_name[link["parent"]]["end"], atol=1e-4)
    fitted = np.mean([link["start"] + link["end"] for link in doc["links"]], 0).reshape(2, 3).mean(0)
    true = np.mean([link["start"] + link["end"] for link in truth["links"]], 0).reshape(2, 3).mean(0)
    assert true[2] > 0.5 and np.linalg.norm(fitted - true) < 1.0  # camera frame: in front of the camera
    # params in physical units
    params = doc["params"]
    assert len(params["root_translation"]) == 3 and len(params["root_rpy"]) == 3 and params["scale"] > 0
    assert set(params["joints"]) == set(names) and all(len(v) == 3 for v in params["joints"].values())
    assert set(params["lengths"]) == set(names)
    # cost, its history, evaluation counts, config, versions, timing
    assert math.isfinite(doc["cost"]) and doc["cost"] >= 0
    assert len(doc["cost_history"]) == 10 and doc["cost"] <= doc["cost_history"][0] + 1e-9
    assert doc["evaluations"]["objective"] >= 32 * 10 and doc["evaluations"]["gradient"] == 0
    assert doc["evaluations"]["point_to_capsule_distances"] > 0
    cfg = doc["config"]
    assert (cfg["algorithm"], cfg["population"], cfg["generations"]) == ("ga", 32, 10)
    assert cfg["memetic_steps"] == 0 and cfg["final_refine_steps"] == 0 and cfg["islands"] == 1
    assert cfg["objective"]["free_space_weight"] == 0
    assert doc["versions"]["jaxpose"] and doc["versions"]["jax"] and doc["versions"]["numpy"]
    assert doc["timing"]["wall_seconds"] > 0
    assert doc["warnings"] == []  # a cloud of the skeleton's size


def test_same_seed_gives_identical_numbers(ga_result, scene, capsys):
    """A second run (with an overlay plot) repeats every number but the timing."""
    pytest.importorskip("matplotlib")
    out = scene / "again.json"
    plot = scene / "overlay.png"
    stdout, _ = _run(capsys, "fit", scene / "depth.png", "--intrinsics", scene / "truth.json", "--seed", "7",
                     "--out", out, "--plot", plot, *FIT)
    again = json.loads(out.read_text())
    assert stdout == ""  # --quiet
    first = {k: v for k, v in ga_result.items() if k != "timing"}
    assert {k: v for k, v in again.items() if k != "timing"} == first
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not [f for f in os.listdir(scene) if f.startswith(".tmp-")]


def test_several_inputs_give_each_the_result_of_its_own_run(ga_result, scene, tmp_path, capsys):
    """``fit A B --out-dir D`` writes D/A.json and D/B.json, each with every number of
    a run on that input alone; the inputs are a depth image and a point cloud."""
    from jaxpose.camera import depth_to_points, foreground_mask
    from jaxpose.io.depth_file import parse_intrinsics

    depth = load_depth(scene / "depth.png")
    pts, _ = depth_to_points(depth, parse_intrinsics(str(scene / "truth.json"), depth.shape))
    np.save(tmp_path / "cloud.npy", pts[foreground_mask(depth).reshape(-1)].astype(np.float32))
    alone = tmp_path / "alone.json"
    _run(capsys, "fit", tmp_path / "cloud.npy", "--seed", "7", "--out", alone, *FIT)
    out_dir = tmp_path / "results"
    out_dir.mkdir()
    stdout, _ = _run(capsys, "fit", scene / "depth.png", tmp_path / "cloud.npy", "--intrinsics", scene / "truth.json",
                     "--seed", "7", "--out-dir", out_dir, *[a for a in FIT if a != "--quiet"])
    assert sorted(os.listdir(out_dir)) == ["cloud.json", "depth.json"]
    assert stdout.startswith("1/2 depth.png spider: cost ") and "\n2/2 cloud.npy spider: cost " in stdout
    strip = lambda d: {k: v for k, v in d.items() if k != "timing"}  # noqa: E731
    assert strip(json.loads((out_dir / "depth.json").read_text())) == strip(ga_result)
    assert strip(json.loads((out_dir / "cloud.json").read_text())) == strip(json.loads(alone.read_text()))


def test_several_inputs_with_a_background_and_plots(scene, tmp_path, capsys):
    """A background image applies to the depth images of a mixed batch (here one that
    measures nothing, so it removes nothing) and leaves the clouds alone; --plots."""
    pytest.importorskip("matplotlib")
    import imageio.v3 as iio

    iio.imwrite(tmp_path / "blank.png", np.zeros((120, 160), np.uint16))
    np.save(tmp_path / "cloud.npy", np.random.default_rng(0).normal([0, 0, 1.5], 0.2, (300, 3)).astype(np.float32))
    out_dir = tmp_path / "results"
    out_dir.mkdir()
    _run(capsys, "fit", scene / "depth.png", tmp_path / "cloud.npy", "--intrinsics", scene / "truth.json",
         "--background", tmp_path / "blank.png", "--out-dir", out_dir, "--plots", *FIT)
    assert sorted(os.listdir(out_dir)) == ["cloud.json", "cloud.png", "depth.json", "depth.png"]
    depth = json.loads((out_dir / "depth.json").read_text())
    assert depth["input"]["background"] == "blank.png"
    assert "background" not in json.loads((out_dir / "cloud.json").read_text())["input"]


def test_a_bad_input_among_several_writes_nothing(scene, tmp_path, capsys):
    out_dir = tmp_path / "results"
    out_dir.mkdir()
    (tmp_path / "broken.ply").write_text("not a cloud\n")
    rc = main(["fit", str(scene / "depth.png"), str(tmp_path / "broken.ply"), "--intrinsics", str(scene / "truth.json"),
               "--out-dir", str(out_dir)] + FIT)
    assert rc == 2 and "broken.ply: not a PLY file" in capsys.readouterr().err
    assert os.listdir(out_dir) == []


@pytest.mark.parametrize("algorithm", ["hc", "cma_es"])
def test_other_algorithms_run_through_the_same_command(algorithm, scene, capsys):
    out = scene / f"{algorithm}.json"
    stdout, _ = _run(capsys, "fit", scene / "depth.png", "--intrinsics", scene / "truth.json",
                     "--algorithm", algorithm, "--out", out, *[a for a in FIT if a != "--quiet"])
    doc = json.loads(out.read_text())
    assert doc["algorithm"] == doc["config"]["algorithm"] == algorithm
    assert math.isfinite(doc["cost"]) and len(doc["links"]) == 8 and len(doc["cost_history"]) == 10
    assert stdout.startswith("spider: cost ") and str(out) in stdout


def test_eval_result_against_truth_as_json(ga_result, scene, capsys):
    stdout, err = _run(capsys, "eval", scene / "result.json", scene / "truth.json", "--json")
    m = json.loads(stdout)
    assert err == "" and m["skeleton"] == "spider" and m["num_links"] == 8
    for kind in ("strict", "symmetric"):
        assert set(m[kind]) >= {"pcp", "pcp_10cm", "pck_10cm", "mpjpe_mm"}
        assert 0 <= m[kind]["pcp"] <= 1 and m[kind]["mpjpe_mm"] >= 0
    assert m["symmetric"]["mpjpe_mm"] <= m["strict"]["mpjpe_mm"] + 1e-9
    assert set(m["per_link"]) == {link["name"] for link in ga_result["links"]}
    # the truth against itself is perfect
    stdout, _ = _run(capsys, "eval", scene / "truth.json", scene / "truth.json", "--json")
    assert json.loads(stdout)["strict"]["pcp"] == 1.0


def test_a_cloud_in_the_wrong_unit_is_fitted_with_a_warning(ga_result, scene, tmp_path, capsys):
    """Millimetres read at 1 cm per unit: ten times the spider's size.  The fit goes on (same
    compiled programs as the other tiny fits), says so in one warning line and in the result."""
    out = tmp_path / "big.json"
    _, err = _run(capsys, "fit", scene / "depth.png", "--intrinsics", scene / "truth.json", "--seed", "7",
                  "--depth-scale", "0.01", "--far", "100", "--out", out, *FIT)
    lines = [line for line in err.splitlines() if line]
    assert len(lines) == 1 and lines[0].startswith(f"jaxpose: warning: {scene / 'depth.png'}: the points spread")
    assert "scale range 0.5 .. 2" in lines[0]
    doc = json.loads(out.read_text())
    assert doc["warnings"] == [lines[0].removeprefix("jaxpose: warning: ")]
    assert doc["params"]["scale"] > 1.9  # near the range's edge (2), as the warning says


def test_a_depth_scale_for_float_pixels_is_not_applied_and_said_so(ga_result, scene, tmp_path, capsys):
    """Float pixels are metres: ``--depth-scale`` leaves them alone, the command says so in
    one warning line, and the result records no scale (the PNG's fit records 0.001)."""
    np.save(tmp_path / "metres.npy", load_depth(scene / "depth.png"))
    out = tmp_path / "float.json"
    _, err = _run(capsys, "fit", tmp_path / "metres.npy", "--intrinsics", scene / "truth.json", "--seed", "7",
                  "--depth-scale", "0.01", "--out", out, *FIT)
    lines = [line for line in err.splitlines() if line]
    assert lines == [f"jaxpose: warning: {tmp_path / 'metres.npy'}: the depth scale 0.01 was not applied: the image "
                     "stores float depths, read as metres (the scale converts integer pixels, as in a 16-bit PNG)"]
    doc = json.loads(out.read_text())
    assert doc["input"]["depth_scale"] is None and doc["warnings"] == [lines[0].removeprefix("jaxpose: warning: ")]
    assert ga_result["input"]["depth_scale"] == 0.001 and ga_result["warnings"] == []
    # the same metres as the PNG, so the same fit
    assert doc["cost"] == pytest.approx(ga_result["cost"], rel=1e-5)


def test_skeleton_command(capsys):
    stdout, _ = _run(capsys, "skeleton", "spider", "--genome")
    lines = stdout.splitlines()
    skel = load_skeleton("spider")
    assert lines[0] == f"spider: 8 links, {skel.num_dof} DOF (genome size)"
    assert sum(line.split()[0] in skel.link_names for line in lines[1:9]) == 8
    assert sum("gene" in line and ":" in line for line in lines[9:]) == skel.num_dof


def test_help_lists_the_commands(capsys):
    rc = main(["--help"])
    out, _ = capsys.readouterr()
    assert rc == 0
    for command in ("fit", "render", "eval", "skeleton"):
        assert f"    {command}" in out


def test_installed_command_reports_one_line_and_status_2(tmp_path):
    """The console script in a fresh process: no traceback, no stray warnings on stderr."""
    exe = os.path.join(os.path.dirname(sys.executable), "jaxpose")
    argv = [exe] if os.path.exists(exe) else [sys.executable, "-m", "jaxpose.cli"]
    p = subprocess.run(argv + ["fit", "missing.png", "--skeleton", "spider"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and p.stdout == ""
    assert p.stderr == "jaxpose: error: missing.png: depth file not found\n"


def test_compilation_cache_folder(tmp_path, monkeypatch):
    import jax

    from jaxpose.cli import enable_compilation_cache

    before = jax.config.jax_compilation_cache_dir
    min_before = jax.config.jax_persistent_cache_min_compile_time_secs
    try:
        monkeypatch.setenv("JAXPOSE_CACHE_DIR", "0")
        assert enable_compilation_cache() is None
        target = tmp_path / "a" / "xla"
        monkeypatch.setenv("JAXPOSE_CACHE_DIR", str(target))
        assert enable_compilation_cache() == str(target)
        assert target.is_dir() and jax.config.jax_compilation_cache_dir == str(target)
        assert jax.config.jax_persistent_cache_min_compile_time_secs == 0.0  # every program is kept
        blocker = tmp_path / "file"
        blocker.write_text("x")
        monkeypatch.setenv("JAXPOSE_CACHE_DIR", str(blocker / "xla"))  # cannot be created: no cache, no error
        assert enable_compilation_cache() is None
    finally:
        jax.config.update("jax_compilation_cache_dir", before)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", min_before)


def test_fit_options_reach_the_config():
    from jaxpose.cli import build_parser
    from jaxpose.commands.fit import config_from_args
    from jaxpose.search import FitConfig

    args = build_parser().parse_args(["fit", "d.png", "--skeleton", "spider", "--coarse-points", "256",
                                      "--islands", "3", "--population", "20", "--generations", "40",
                                      "--tie-lengths", "--limb-sweep", "7", "--pivot-sweep", "5", "--turns", "2",
                                      "--restarts", "3", "--restart-apart", "0.25", "--scale", "1",
                                      "--max-range", "4"])
    cfg = config_from_args(args)
    assert (cfg.coarse_points, cfg.islands, cfg.population, cfg.generations, cfg.limb_sweep, cfg.pivot_sweep,
            cfg.turns, cfg.restarts, cfg.restart_apart, cfg.scale) == (256, 3, 20, 40, 7, 5, 2, 3, 0.25, 1.0)
    assert cfg.objective.max_range == 4.0
    assert cfg.tie_lengths
    default = config_from_args(build_parser().parse_args(["fit", "d.png", "--skeleton", "spider"]))
    assert default == FitConfig()


@pytest.mark.parametrize("flag,value", [("--turns", "4"), ("--turns", "-1"), ("--restarts", "0"),
                                        ("--restart-apart", "-0.2"), ("--scale", "0")])
def test_impossible_turns_and_restarts_are_one_line_naming_the_flag(flag, value, capsys):
    from jaxpose.cli import build_parser
    from jaxpose.commands.fit import config_from_args
    from jaxpose.errors import ConfigError

    with pytest.raises(ConfigError, match=rf"^{flag} must be"):
        config_from_args(build_parser().parse_args(["fit", "d.png", "--skeleton", "spider", flag, value]))


def test_track_options_reach_the_config():
    from jaxpose.cli import build_parser
    from jaxpose.commands.track import track_config_from_args
    from jaxpose.tracking import TrackConfig

    args = build_parser().parse_args(["track", "frames", "--skeleton", "spider", "--out-dir", "o",
                                      "--track-length-window", "1.02", "--track-recheck", "30", "--scale", "1.1",
                                      "--max-range", "3.5"])
    cfg = track_config_from_args(args)
    assert (cfg.length_window, cfg.recheck_every, cfg.fit.scale, cfg.fit.objective.max_range) == (1.02, 30, 1.1, 3.5)
    plain = build_parser().parse_args(["track", "f", "--skeleton", "spider", "--out-dir", "o"])
    assert track_config_from_args(plain) == TrackConfig()
