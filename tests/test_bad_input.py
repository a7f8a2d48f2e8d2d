"""Every bad input gets one clear error: ``jaxpose: error: <message>`` and exit status 2.

The cases are the rows of ``docs/errors.md``: :func:`test_documented_error` reads the
table, runs each row's example command (in a folder holding the row's input files)
and checks the exit status, that stderr is exactly the documented line, and which
documented exception type carried it.  The other tests cover what a command line
cannot show (atomic writes, Ctrl-C, the library's exception types).
"""

from __future__ import annotations

import errno
import json
import os
import re
import shlex
import sys
from pathlib import Path

import numpy as np
import pytest

import jaxpose.cli as cli
from jaxpose import errors
from jaxpose.camera import KINECT_V1, Intrinsics, check_intrinsics, depth_to_cloud
from jaxpose.errors import ConfigError, DepthError, IntrinsicsError, JaxposeError, SkeletonError
from jaxpose.io.depth_file import load_depth, parse_intrinsics
from jaxpose.io.atomic import atomic_write, write_json
from jaxpose.io.skeleton_file import MAX_LINKS, load_skeleton, skeleton_from_dict
from jaxpose.io.truth import TruthError

DOC = Path(__file__).resolve().parent.parent / "docs" / "errors.md"
H, W = KINECT_V1.height, KINECT_V1.width


# --------------------------------------------------------------------------- input files


def _png_header_only(path: Path, w: int, h: int, bits: int = 16, colour: int = 0) -> None:
    """A PNG whose header announces ``w x h`` pixels (no pixel data follows)."""
    ihdr = w.to_bytes(4, "big") + h.to_bytes(4, "big") + bytes([bits, colour, 0, 0, 0])
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + len(ihdr).to_bytes(4, "big") + b"IHDR" + ihdr + b"\0\0\0\0")


def _npy_header_only(path: Path, shape, descr: str = "<f4", extra: bytes = b"") -> None:
    with open(path, "wb") as f:
        np.lib.format.write_array_header_1_0(f, {"descr": descr, "fortran_order": False, "shape": shape})
        f.write(extra)


def _link(name, parent=None, **kw):
    lines = ["[[link]]", f'name = "{name}"'] + ([f'parent = "{parent}"'] if parent else [])
    return "\n".join(lines + [f"{k} = {json.dumps(v)}" for k, v in kw.items()]) + "\n"


def _ply_header(n: int, props: str, element: str = "vertex") -> bytes:
    return (f"ply\nformat binary_little_endian 1.0\nelement {element} {n}\n"
            + "".join(f"property float {p}\n" for p in props) + "end_header\n").encode()


def _make_clouds(d: Path) -> None:
    """The point-cloud files of the P rows."""
    pts = (np.random.default_rng(0).normal(size=(100, 3)) * 0.2 + [0, 0, 1.5]).astype(np.float32)
    np.save(d / "cloud.npy", pts)
    np.save(d / "nan_cloud.npy", np.full((100, 3), np.nan, np.float32))
    np.save(d / "mm.npy", np.tile(np.float32([0, 0, 1500]), (100, 1)) + pts * [1, 1, 0])
    np.save(d / "tiny.npy", pts[:20])
    np.save(d / "same.npy", np.ones((100, 3), np.float32))
    np.save(d / "gl.npy", np.tile(np.float32([0, 0, -1.5]), (100, 1)) + pts * [1, 1, 0])
    np.save(d / "int_cloud.npy", (pts * 1000).astype(np.int32))
    (d / "empty.pcd").write_bytes(b"")
    (d / "notes.ply").write_text("not a cloud\n")
    (d / "faces.ply").write_text("ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int vertex_indices\n"
                                 "end_header\n")
    (d / "noz.ply").write_bytes(_ply_header(100, "xy") + pts[:, :2].tobytes())
    (d / "cut.ply").write_bytes(_ply_header(100, "xyz") + pts[:10].tobytes())
    pcd = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA {}\n"
    (d / "zipped.pcd").write_text(pcd.format("binary_zipped"))
    # an LZF stream whose first control byte refers back before the start of the output
    (d / "corrupt.pcd").write_bytes(pcd.format("binary_compressed").encode() + b"\x03\0\0\0\x0c\0\0\0\x20\x05\x00")
    (d / "words.xyz").write_text("# x y z\n1 2 3\n4 five 6\n")


def make_inputs(d: Path) -> None:
    """Every input file the rows of docs/errors.md refer to."""
    import imageio.v3 as iio

    good = np.zeros((H, W), np.float32)
    good[200:260, 300:360] = 1.5  # 3600 points at 1.5 m
    np.save(d / "good.npy", good)
    small = np.zeros((120, 160), np.float32)
    small[50:70, 70:90] = 1.5
    np.save(d / "small.npy", small)
    np.save(d / "zeros.npy", np.zeros((H, W), np.float32))
    np.save(d / "nan.npy", np.full((H, W), np.nan, np.float32))
    np.save(d / "far.npy", np.full((H, W), 20.0, np.float32))
    few = np.zeros((H, W), np.float32)
    few[100:104, 100:104] = 2.0  # 16 points
    np.save(d / "few.npy", few)
    np.save(d / "line.npy", np.ones((1, W), np.float32))
    np.save(d / "cube.npy", np.ones((H, W, 4), np.float32))
    np.save(d / "strings.npy", np.array([["a", "b"], ["c", "d"]]))
    _npy_header_only(d / "huge.npy", (100_000, 100_000))
    _npy_header_only(d / "trunc.npy", (H, W), extra=b"\0" * 100)
    np.savez(d / "archive.npz", depth=good)
    os.replace(d / "archive.npz", d / "archive.npy")
    _make_clouds(d)
    (d / "notes.png").write_text("not a picture\n")
    (d / "empty.png").write_bytes(b"")
    iio.imwrite(d / "rgb.png", np.zeros((H, W, 3), np.uint8))
    iio.imwrite(d / "gray8.png", np.zeros((H, W), np.uint8))
    _png_header_only(d / "huge.png", 100_000, 100_000)
    # intrinsics
    (d / "broken.json").write_text('{"fx": 525 "fy": 525}')
    (d / "partial.json").write_text('{"fx": 525}')
    (d / "cam640.json").write_text(json.dumps({"fx": 525, "fy": 525, "cx": 319.5, "cy": 239.5,
                                               "width": 640, "height": 480}))
    # skeletons
    (d / "empty.toml").write_text("")
    (d / "broken.toml").write_text('[[link]\nname = "a"\n')
    (d / "broken_skel.json").write_text('{"link": [')
    (d / "binary.toml").write_bytes(b"\xff\xfe\x00\x01")
    (d / "list.json").write_text("[1, 2]")
    (d / "nolinks.toml").write_text('name = "x"\n')
    (d / "unknown_parent.toml").write_text(_link("a") + _link("b", "c"))
    (d / "cycle.toml").write_text(_link("a", "b") + _link("b", "a"))
    (d / "duplicate.toml").write_text(_link("a") + _link("a"))
    (d / "neg_length.toml").write_text(_link("a", length=-0.1))
    (d / "neg_radius.toml").write_text(_link("a", radius=-0.01))
    (d / "inverted.toml").write_text(_link("a", limits=[[30, -30], [0, 0], [0, 0]]))
    (d / "joint.toml").write_text(_link("a", joint="slider"))
    (d / "zero.toml").write_text(_link("a", length=0, radius=0))
    (d / "typo.toml").write_text(_link("a", lenght=0.1))
    (d / "toplevel.toml").write_text("scale = 2\n" + _link("a"))
    (d / "string_length.toml").write_text(_link("a", length="long"))
    (d / "attach.toml").write_text(_link("a") + _link("b", "a", attach="end"))
    with open(d / "huge.toml", "wb") as f:
        f.truncate(17 * 1024 * 1024)
    (d / "many.toml").write_text("".join(_link(f"l{i}") for i in range(MAX_LINKS + 1)))
    (d / "broken.urdf").write_text('<robot name="r"><link name="a">')
    (d / "broken.xml").write_text("<mujoco><worldbody>")
    (d / "outdir").mkdir()
    (d / "sub").mkdir()
    np.save(d / "sub" / "good.npy", good)
    (d / "readonly").mkdir()
    os.chmod(d / "readonly", 0o555)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("inputs")
    make_inputs(d)
    yield d
    os.chmod(d / "readonly", 0o755)


# --------------------------------------------------------------------------- running the command line


def run_cli(argv, capsys, monkeypatch=None):
    """``jaxpose argv`` in-process -> (status, stdout, stderr lines, exception type name or None)."""
    seen = []
    one_line = cli.one_line

    def record(e):
        seen.append(type(e).__name__)
        return one_line(e)

    patch = monkeypatch or pytest.MonkeyPatch()
    patch.setattr(cli, "one_line", record)
    try:
        rc = cli.main(argv)
    finally:
        if monkeypatch is None:
            patch.undo()
    out, err = capsys.readouterr()
    return rc, out, [line for line in err.splitlines() if line.strip()], (seen[0] if seen else None)


def _hide_matplotlib(mp):
    for name in [m for m in sys.modules if m == "matplotlib" or m.startswith("matplotlib.")]:
        mp.delitem(sys.modules, name)
    mp.setitem(sys.modules, "matplotlib", None)  # `import matplotlib` raises ImportError


def _no_search(mp):
    import jaxpose.pipeline

    def fail(*a, **k):
        raise AssertionError("the search started although the input is bad")

    mp.setattr(jaxpose.pipeline, "fit_cloud", fail)


def _read_only(mp):
    real = os.access
    mp.setattr(os, "access", lambda p, mode, **kw: False if (mode & os.W_OK and str(p).endswith("readonly"))
               else real(p, mode, **kw))


def _needs_mujoco(mp):
    pytest.importorskip("mujoco")


# Rows that need more than their input files.
SETUP = {
    "C9": [_read_only],
    "C13": [_hide_matplotlib, _no_search],
    "S25": [_needs_mujoco],
}


def documented_rows():
    """``(id, command, message, exception, status)`` of every row of docs/errors.md run by this test."""
    rows = []
    for line in DOC.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 7 or "test_documented_error" not in cells[6]:
            continue
        code = lambda c: re.findall(r"`([^`]*)`", c)  # noqa: E731
        rows.append(pytest.param(cells[0], code(cells[2])[0], code(cells[3])[0], cells[4].strip("`"),
                                 int(cells[5]), id=cells[0]))
    return rows


ROWS = documented_rows()


def test_the_table_has_every_class_of_bad_input():
    ids = [r.values[0] for r in ROWS]
    assert len(ids) == len(set(ids)) and len(ids) >= 60
    for prefix in "DISCP":
        assert any(i.startswith(prefix) for i in ids)


@pytest.mark.parametrize("row,command,message,exception,status", ROWS)
def test_documented_error(row, command, message, exception, status, inputs, capsys, monkeypatch):
    """The row's command gives exactly its documented line, status and exception type."""
    monkeypatch.chdir(inputs)
    for setup in SETUP.get(row, []):
        setup(monkeypatch)
    argv = shlex.split(command)
    assert argv[0] == "jaxpose"
    rc, out, err, exc = run_cli(argv[1:], capsys, monkeypatch)
    assert rc == status, (command, err)
    assert len(err) == 1, err  # one line, never a traceback
    if message.endswith("..."):
        assert err[0].startswith(message[:-3]), (err[0], message)
    else:
        assert err[0] == message
    if not exception.isidentifier():  # "— (parser)": argparse, no exception
        assert exc is None
    else:
        assert exc == exception
        assert issubclass(getattr(errors, exception, TruthError), JaxposeError)
    assert not os.path.exists("result.json")
    assert not [f for f in os.listdir(".") if f.startswith(".tmp-")]


# --------------------------------------------------------------------------- outputs are atomic


class Boom(Exception):
    pass


@pytest.mark.parametrize("exc", [KeyboardInterrupt, Boom])
def test_atomic_write_interrupted_midway_leaves_no_partial_file(tmp_path, exc):
    path = tmp_path / "result.json"

    def writer(f):
        f.write('{"half": ')
        f.flush()
        raise exc()

    with pytest.raises(exc):
        atomic_write(path, writer)
    assert os.listdir(tmp_path) == []
    # an existing file survives a failed rewrite untouched
    write_json(path, {"ok": 1})
    with pytest.raises(exc):
        atomic_write(path, writer)
    assert json.loads(path.read_text()) == {"ok": 1}
    assert os.listdir(tmp_path) == ["result.json"]
    # NaN is not JSON: refused before anything is replaced
    with pytest.raises(ValueError):
        write_json(path, {"cost": float("nan")})
    assert json.loads(path.read_text()) == {"ok": 1} and os.listdir(tmp_path) == ["result.json"]


def test_ctrl_c_during_the_fit_leaves_no_result(inputs, tmp_path, capsys, monkeypatch):
    import jaxpose.pipeline

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(jaxpose.pipeline, "fit_cloud", interrupted)
    out = tmp_path / "result.json"
    rc, _, err, _ = run_cli(["fit", str(inputs / "good.npy"), "--skeleton", "spider", "--out", str(out)], capsys)
    assert rc == 130
    assert err == ["jaxpose: interrupted (no partially written output file is left behind)"]
    assert os.listdir(tmp_path) == []


def test_failing_fit_leaves_no_result(inputs, tmp_path, capsys, monkeypatch):
    """An error found only once the fit runs (here: a depth error) writes nothing."""
    out = tmp_path / "result.json"
    rc, _, err, exc = run_cli(["fit", str(inputs / "few.npy"), "--skeleton", "spider", "--out", str(out)], capsys)
    assert rc == 2 and exc == "DepthError" and len(err) == 1
    assert os.listdir(tmp_path) == []


def test_os_error_while_writing_is_one_line_with_status_1(capsys, monkeypatch):
    import jaxpose.commands.skeleton as cmd

    def disk_full(args):
        raise OSError(errno.ENOSPC, "No space left on device", "result.json")

    monkeypatch.setattr(cmd, "run", disk_full)
    rc, _, err, _ = run_cli(["skeleton", "spider"], capsys)
    assert rc == 1 and err == ["jaxpose: error: result.json: No space left on device"]


def test_out_folder_on_a_read_only_file_system(inputs, tmp_path, capsys, monkeypatch):
    """Writability is probed by creating a file, so root and read-only mounts are caught too."""
    import tempfile

    def read_only_fs(*a, **k):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(tempfile, "TemporaryFile", read_only_fs)
    rc, _, err, exc = run_cli(["fit", str(inputs / "good.npy"), "--skeleton", "spider",
                               "--out", str(tmp_path / "r.json")], capsys)
    assert rc == 2 and exc == "ConfigError"
    assert err == [f"jaxpose: error: --out {tmp_path / 'r.json'}: directory {tmp_path} is not writable "
                   "(Read-only file system)"]


def test_a_closed_output_pipe_is_not_an_error(capsys, monkeypatch):
    """``jaxpose skeleton spider --genome | head -1``: the reader leaves; no error line."""
    class ClosedPipe:
        def write(self, text):
            raise BrokenPipeError(errno.EPIPE, "Broken pipe")

        def flush(self):
            pass

    monkeypatch.setattr(sys, "stdout", ClosedPipe())
    assert cli.main(["skeleton", "spider", "--genome"]) == 141
    assert capsys.readouterr().err == ""


def test_help_and_version_are_not_errors(capsys):
    assert cli.main(["--version"]) == 0
    assert cli.main(["fit", "--help"]) == 0
    out, err = capsys.readouterr()
    assert "--skeleton" in out and err == ""


# --------------------------------------------------------------------------- the library raises the documented types


def test_library_functions_raise_documented_types(inputs):
    with pytest.raises(DepthError, match="depth file not found"):
        load_depth(inputs / "missing.png")
    with pytest.raises(DepthError, match="image has 3 channels"):
        load_depth(inputs / "rgb.png")
    with pytest.raises(DepthError, match="depth scale"):
        load_depth(inputs / "good.npy", depth_scale=-1)
    with pytest.raises(IntrinsicsError, match="focal lengths must be positive"):
        check_intrinsics(Intrinsics(0.0, 1.0, 1.0, 1.0, 4, 4))
    with pytest.raises(IntrinsicsError, match="must be numbers"):
        check_intrinsics(Intrinsics("a", 1.0, 1.0, 1.0, 4, 4))
    with pytest.raises(IntrinsicsError, match="width and height"):
        check_intrinsics(Intrinsics(1.0, 1.0, 1.0, 1.0, 0, 4))
    with pytest.raises(IntrinsicsError, match="4 numbers"):
        parse_intrinsics("1,2")
    with pytest.raises(SkeletonError, match="cycle"):
        load_skeleton(inputs / "cycle.toml")
    with pytest.raises(SkeletonError, match="no links"):
        skeleton_from_dict({"link": []})
    good = np.load(inputs / "good.npy")
    k = KINECT_V1
    with pytest.raises(DepthError, match="numeric"):
        depth_to_cloud(good.astype(complex), k)
    with pytest.raises(DepthError, match="background image is 3x3"):
        depth_to_cloud(good, k, background=np.ones((3, 3)))
    with pytest.raises(DepthError, match="near/far"):
        depth_to_cloud(good, k, near=2.0, far=1.0)
    with pytest.raises(DepthError, match="max_points"):
        depth_to_cloud(good, k, max_points=0)
    for exc in (SkeletonError, DepthError, IntrinsicsError, ConfigError, TruthError):
        assert issubclass(exc, JaxposeError) and issubclass(exc, ValueError)


def test_library_pipeline_validates_options(inputs):
    from jaxpose.pipeline import InputOptions, load_observation
    from jaxpose.search import FitConfig

    for bad, match in [(dict(near=2.0, far=1.0), "near < far"), (dict(depth_scale=0.0), "depth_scale"),
                       (dict(max_points=0), "max_points"), (dict(background_tolerance=-1.0), "background_tolerance"),
                       (dict(far=float("inf")), "finite"), (dict(remove_planes=9), "remove_planes"),
                       (dict(remove_planes=1.5), "remove_planes"), (dict(plane_tolerance=-0.1), "plane_tolerance")]:
        with pytest.raises(ConfigError, match=match):
            load_observation(str(inputs / "good.npy"), InputOptions(**bad))
    with pytest.raises(ConfigError, match="population"):
        FitConfig(population=1).validate()
    with pytest.raises(ConfigError, match="generations"):
        FitConfig(generations=0).validate()
    with pytest.raises(ConfigError, match="unknown algorithm"):
        FitConfig(algorithm="sgd").validate()


# --------------------------------------------------------------------------- what is *not* an error


def test_missing_measurements_are_not_errors(tmp_path):
    """NaN, inf, -inf, 0 and negative pixels in a float .npy are missing measurements."""
    from jaxpose.pipeline import InputOptions, load_observation

    rng = np.random.default_rng(0)
    d = np.full((120, 160), np.nan, np.float32)
    d[40:80, 60:100] = 1.5 + 0.01 * rng.standard_normal((40, 40))
    holes = rng.random((120, 160)) < 0.1
    d[holes] = rng.choice(np.array([np.nan, np.inf, -np.inf, 0.0, -1.0], np.float32), holes.sum())
    np.save(tmp_path / "holes.npy", d)
    depth = load_depth(tmp_path / "holes.npy")
    assert depth.dtype == np.float32 and not np.any(depth <= 0)
    assert np.isnan(depth[holes]).all() and np.isfinite(depth).sum() >= 0.8 * 1600
    _, k, cloud = load_observation(str(tmp_path / "holes.npy"),
                                   InputOptions(intrinsics="150,150,79.5,59.5", max_points=256))
    assert k.width == 160 and np.all(np.isfinite(np.asarray(cloud.points)))
    assert int(np.sum(np.asarray(cloud.weights) > 0)) == 256


def test_integer_npy_holds_stored_units_like_a_png(tmp_path):
    mm = np.zeros((4, 5), np.uint16)
    mm[1:3, 1:4] = 1500
    np.save(tmp_path / "mm.npy", mm)
    d = load_depth(tmp_path / "mm.npy")
    assert np.allclose(d[1:3, 1:4], 1.5) and np.isnan(d[0]).all()
    assert np.allclose(load_depth(tmp_path / "mm.npy", depth_scale=0.0001)[1, 1], 0.15)


@pytest.mark.filterwarnings("ignore:ImageIO's vendored tifffile:DeprecationWarning")
@pytest.mark.parametrize("ext", [".tif", ".pfm"])
def test_float_images_are_metres_integer_images_stored_units(tmp_path, ext):
    """A float depth map (a renderer's Z pass, ROS 32FC1) holds metres whatever the depth
    scale; a 16-bit TIFF holds millimetres like a PNG."""
    import imageio.v3 as iio

    rng = np.random.default_rng(3)
    metres = rng.uniform(0.5, 4.0, (30, 40)).astype(np.float32)
    metres[3:7, 5:9] = np.nan
    metres[10, :] = 0.0
    iio.imwrite(tmp_path / f"m{ext}", metres)
    d = load_depth(tmp_path / f"m{ext}")
    ok = np.isfinite(metres) & (metres > 0)
    np.testing.assert_array_equal(d[ok], metres[ok])
    assert np.isnan(d[~ok]).all()
    np.testing.assert_array_equal(load_depth(tmp_path / f"m{ext}", depth_scale=0.0002)[ok], metres[ok])
    if ext == ".tif":
        mm = np.round(np.nan_to_num(metres) * 1000).astype(np.uint16)
        iio.imwrite(tmp_path / "mm.tif", mm)
        got = load_depth(tmp_path / "mm.tif")
        np.testing.assert_allclose(got[mm > 0], mm[mm > 0] * np.float32(0.001), rtol=1e-6)
        assert np.isnan(got[mm == 0]).all()


def test_the_depth_scale_is_recorded_and_warned_about_only_where_it_applies(tmp_path):
    """Applied to integer pixels in the image or its background; float pixels are metres."""
    from jaxpose.pipeline import InputOptions, read_observation, unused_depth_scale

    metres = np.full((30, 40), 2.0, np.float32)
    metres[10:20, 15:25] = 1.5
    np.save(tmp_path / "m.npy", metres)
    np.save(tmp_path / "bg_m.npy", np.full((30, 40), 2.0, np.float32))
    np.save(tmp_path / "bg_mm.npy", np.full((30, 40), 2000, np.uint16))
    for background, scaled in ((None, False), ("bg_m.npy", False), ("bg_mm.npy", True)):
        opts = InputOptions("30,30,19.5,14.5", depth_scale=0.001, background=background and str(tmp_path / background))
        got = read_observation(str(tmp_path / "m.npy"), opts)
        assert got[3] is scaled and int(np.sum(np.asarray(got[2].weights) > 0)) > 0
        odd = InputOptions(opts.intrinsics, depth_scale=0.002, background=opts.background)
        assert (unused_depth_scale(odd, scaled, "m.npy") is None) is scaled
        assert unused_depth_scale(opts, scaled, "m.npy") is None  # the default scale draws no warning


def test_special_files_are_refused_without_blocking(tmp_path):
    os.mkfifo(tmp_path / "pipe.png")  # opening a FIFO would wait for a writer forever
    with pytest.raises(DepthError, match="not a regular file"):
        load_depth(tmp_path / "pipe.png")
    os.rename(tmp_path / "pipe.png", tmp_path / "pipe.toml")
    with pytest.raises(SkeletonError, match="not a regular file"):
        load_skeleton(tmp_path / "pipe.toml")
    os.rename(tmp_path / "pipe.toml", tmp_path / "pipe.json")
    with pytest.raises(IntrinsicsError, match="not a regular file"):
        parse_intrinsics(str(tmp_path / "pipe.json"), (480, 640))


def test_intrinsics_from_a_truth_or_result_file(tmp_path):
    cam = {"fx": 150.0, "fy": 150.0, "cx": 79.5, "cy": 59.5, "width": 160, "height": 120}
    (tmp_path / "truth.json").write_text(json.dumps({"camera": {"intrinsics": cam}}))
    (tmp_path / "result.json").write_text(json.dumps({"input": {"intrinsics": cam}}))
    for name in ("truth.json", "result.json"):
        k = parse_intrinsics(str(tmp_path / name), (120, 160))
        assert k == Intrinsics(**cam)


def test_deep_chain_of_250_links_works(tmp_path, capsys):
    """A long serial chain (>= 200 links) loads, describes and poses without recursion limits."""
    from jaxpose.kinematics import forward_kinematics
    from jaxpose.skeleton import rest_pose

    n = 250
    text = 'name = "chain"\n' + "".join(
        _link(f"l{i}", f"l{i - 1}" if i else None, joint="hinge", axis=[0, 0, 1], limits=[[-5, 5]],
              length=0.01, radius=0.002) for i in reversed(range(n)))  # children before parents
    (tmp_path / "chain.toml").write_text(text)
    skel = load_skeleton(tmp_path / "chain.toml")
    assert skel.num_links == n and len(skel.levels) == n and skel.num_dof == 7 + n
    links = forward_kinematics(skel, rest_pose(skel))
    end = np.asarray(links.end)
    assert np.all(np.isfinite(end)) and np.allclose(end[-1], [0.01 * n, 0, 0], atol=1e-4)
    rc = cli.main(["skeleton", str(tmp_path / "chain.toml")])
    out, _ = capsys.readouterr()
    assert rc == 0 and out.startswith(f"chain: {n} links, {7 + n} DOF")
