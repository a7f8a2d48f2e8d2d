"""Property fuzzing of the readers: whatever the input, only the documented
:class:`~jaxpose.errors.JaxposeError` subclass of the reader may escape
(``SkeletonError`` from skeleton readers, ``DepthError`` from depth readers,
``IntrinsicsError`` from intrinsics), or a valid result comes back.
"""

from __future__ import annotations

import io
import json
import os
import tempfile
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from jaxpose.camera import Intrinsics, depth_to_cloud, sensor_points_to_cloud
from jaxpose.errors import DepthError, IntrinsicsError, SkeletonError
from jaxpose.io.cloud_file import load_points
from jaxpose.io.depth_file import load_depth, parse_intrinsics
from jaxpose.io.skeleton_file import load_skeleton, skeleton_from_dict
from jaxpose.skeleton import Skeleton

# imageio warns about its legacy plugins (TIFF, DICOM) when it probes random bytes
pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

# 50 fixed examples per property in the test suite; JAXPOSE_FUZZ_EXAMPLES=2000 for a deeper, random search.
_DEEP = int(os.environ.get("JAXPOSE_FUZZ_EXAMPLES", "0"))
FUZZ = settings(max_examples=_DEEP or 50, deadline=None, derandomize=not _DEEP,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])


@pytest.fixture(scope="module")
def workdir():
    with tempfile.TemporaryDirectory(prefix="jaxpose-fuzz-") as d:
        yield d


def _write(workdir, name, data) -> str:
    path = os.path.join(workdir, name)
    with open(path, "wb") as f:
        f.write(data if isinstance(data, bytes) else data.encode("utf-8", "surrogatepass"))
    return path


# --------------------------------------------------------------------------- skeletons

scalars = st.one_of(
    st.none(), st.booleans(), st.integers(-(2**70), 2**70), st.integers(-3, 3),
    st.floats(allow_nan=True, allow_infinity=True), st.floats(-1.0, 1.0), st.floats(0.0, 200.0),
    st.text(max_size=8), st.sampled_from(["a", "b", "c", "ball", "hinge", "fixed", "slider", ""]),
)
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                       st.dictionaries(st.text(max_size=6), inner, max_size=3)),
                      max_leaves=12)
vec3 = st.lists(st.one_of(st.floats(-1, 1), st.integers(-2, 2), scalars), min_size=0, max_size=4)
pair = st.lists(st.one_of(st.floats(-200, 200), scalars), min_size=0, max_size=3)
link_fields = {
    "name": st.one_of(st.sampled_from(["a", "b", "c", "d"]), scalars),
    "parent": st.one_of(st.sampled_from(["a", "b", "c", "d", "zz"]), scalars),
    "joint": st.one_of(st.sampled_from(["ball", "hinge", "fixed", "slider"]), scalars),
    "offset": st.one_of(vec3, values),
    "attach": st.one_of(st.floats(-1, 2), scalars),
    "rest": st.one_of(vec3, values),
    "axis": st.one_of(vec3, values),
    "limits": st.one_of(st.lists(pair, max_size=4), values),
    "length": st.one_of(st.floats(-0.1, 0.5), scalars),
    "length_range": st.one_of(pair, values),
    "radius": st.one_of(st.floats(-0.01, 0.05), scalars),
    "bogus": values,
}
links = st.fixed_dictionaries({}, optional=link_fields)
descriptions = st.one_of(
    st.fixed_dictionaries({"link": st.lists(links, max_size=5)},
                          optional={"name": scalars, "scale_range": st.one_of(pair, values), "extra": values}),
    values,
)


def _skeleton_or_documented_error(fn, *args, **kw):
    try:
        out = fn(*args, **kw)
    except SkeletonError as e:
        assert str(e) and "\n" not in str(e).strip()
        return None
    assert isinstance(out, Skeleton)
    return out


@FUZZ
@given(data=descriptions)
def test_random_skeleton_structures(data):
    skel = _skeleton_or_documented_error(skeleton_from_dict, data, source="fuzz.toml")
    if skel is not None:  # a valid one: finite numbers, a tree in topological order
        assert all(p < i for i, p in enumerate(skel.parents))
        for leaf in (skel.offset, skel.length, skel.radius, skel.angle_lo, skel.angle_hi):
            assert np.all(np.isfinite(np.asarray(leaf)))


@FUZZ
@given(data=descriptions)
def test_random_skeleton_json_files(workdir, data):
    try:
        text = json.dumps(data, allow_nan=True)
    except (ValueError, TypeError):
        return
    _skeleton_or_documented_error(load_skeleton, _write(workdir, "fuzz.json", text))


toml_text = st.one_of(
    st.text(max_size=200),
    st.lists(st.sampled_from([
        "[[link]]\n", 'name = "a"\n', 'name = "b"\n', 'parent = "a"\n', 'parent = "b"\n', "length = 0.1\n",
        "length = -1\n", "length = 0\n", "radius = 0\n", "radius = -1\n", 'joint = "hinge"\n', 'joint = "x"\n',
        "limits = [[-10, 10]]\n", "limits = [[10, -10], [0, 0], [0, 0]]\n", "axis = [0, 0, 0]\n",
        "attach = 0.5\n", "attach = nan\n", "offset = [1, 2]\n", "length_range = [0.2, 0.1]\n",
        "scale_range = [0, 1]\n", "rest = [inf, 0, 0]\n", "= 1\n", "[link]\n", '"\n', "x = 1979-05-27\n",
        "length = 99999999999999999999\n", "[[link.x]]\n",
    ]), max_size=16).map("".join),
)


@FUZZ
@given(text=toml_text)
def test_random_skeleton_toml_files(workdir, text):
    _skeleton_or_documented_error(load_skeleton, _write(workdir, "fuzz.toml", text))


@FUZZ
@given(raw=st.binary(max_size=200), ext=st.sampled_from([".toml", ".json", ".urdf"]))
def test_random_bytes_as_skeleton_files(workdir, raw, ext):
    _skeleton_or_documented_error(load_skeleton, _write(workdir, "fuzz" + ext, raw))


# --------------------------------------------------------------------------- depth images


def _depth_or_documented_error(path):
    try:
        d = load_depth(path)
    except DepthError as e:
        assert str(e).startswith(path) and "\n" not in str(e)
        return None
    assert d.ndim == 2 and d.dtype == np.float32 and not np.any(d <= 0)
    return d


def _png_bytes(arr) -> bytes:
    import imageio.v3 as iio

    buf = io.BytesIO()
    iio.imwrite(buf, arr, extension=".png")
    return buf.getvalue()


def _npy_bytes(arr) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    return buf.getvalue()


small_images = st.one_of(
    hnp.arrays(st.sampled_from([np.uint16, np.uint8]), hnp.array_shapes(min_dims=2, max_dims=2, max_side=12)),
    hnp.arrays(np.uint8, st.tuples(st.integers(1, 6), st.integers(1, 6), st.sampled_from([3, 4]))),
)
npy_arrays = hnp.arrays(
    st.sampled_from([np.float32, np.float64, np.float16, np.int16, np.uint16, np.int64, np.bool_, np.complex64,
                     np.dtype("U2"), np.dtype([("a", "<f4")])]),
    hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=8),
)


def _corrupt(data: bytes, edits) -> bytes:
    b = bytearray(data)
    for pos, val in edits:
        if b:
            b[pos % len(b)] = val
    return bytes(b)


edits = st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 255)), max_size=4)


@FUZZ
@given(raw=st.binary(max_size=300), prefix=st.sampled_from([b"", b"\x89PNG\r\n\x1a\n", b"\x93NUMPY\x01\x00"]),
       ext=st.sampled_from([".png", ".npy", ".tif"]))
def test_random_bytes_as_depth_files(workdir, raw, prefix, ext):
    _depth_or_documented_error(_write(workdir, "fuzz" + ext, prefix + raw))


@FUZZ
@given(img=small_images, cut=st.integers(0, 400), edit=edits)
def test_corrupted_png_files(workdir, img, cut, edit):
    data = _corrupt(_png_bytes(img), edit)
    data = data[: len(data) - cut] if cut < len(data) else data
    _depth_or_documented_error(_write(workdir, "fuzz.png", data))


@FUZZ
@given(arr=npy_arrays, cut=st.integers(0, 64), edit=edits)
def test_corrupted_npy_files(workdir, arr, cut, edit):
    data = _corrupt(_npy_bytes(arr), edit)
    data = data[: len(data) - cut] if cut < len(data) else data
    _depth_or_documented_error(_write(workdir, "fuzz.npy", data))


intrinsics = st.builds(
    Intrinsics, st.one_of(st.floats(allow_nan=True), st.floats(1, 100)), st.one_of(st.floats(), st.floats(1, 100)),
    st.one_of(st.floats(), st.floats(0, 8)), st.one_of(st.floats(), st.floats(0, 8)),
    st.integers(-1, 10), st.integers(-1, 10),
)
def _cast(args):
    arr, dtype = args
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return arr.astype(dtype)


depth_arrays = st.tuples(
    hnp.arrays(np.float64, hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=10),
               elements=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(0.2, 3.0), st.just(0.0))),
    st.sampled_from([np.float32, np.float64, np.float16, np.uint16, np.int32, np.bool_, np.complex64, np.object_,
                     np.dtype("U4")]),
).map(_cast)


@FUZZ
@given(depth=depth_arrays, k=intrinsics, near=st.floats(-1, 3), far=st.floats(-1, 10),
       max_points=st.integers(-1, 40), background=st.none() | depth_arrays, min_points=st.integers(0, 5))
def test_random_arrays_to_cloud(depth, k, near, far, max_points, background, min_points):
    try:
        cloud = depth_to_cloud(depth, k, near, far, background, max_points, min_points=min_points)
    except (DepthError, IntrinsicsError):
        return
    pts, w = np.asarray(cloud.points), np.asarray(cloud.weights)
    assert pts.shape == (max_points, 3) and w.shape == (max_points,)
    assert np.all(np.isfinite(pts[w > 0])) and int((w > 0).sum()) >= min(min_points, max_points)


@FUZZ
@given(spec=st.one_of(st.text(max_size=30), st.lists(st.one_of(st.floats(), st.integers(-5, 700)), max_size=5)
                      .map(lambda v: ",".join(map(str, v)))),
       shape=st.one_of(st.none(), st.tuples(st.integers(1, 600), st.integers(1, 800))))
def test_random_intrinsics_specs(spec, shape):
    try:
        k = parse_intrinsics(spec, shape)
    except IntrinsicsError:
        return
    assert k.fx > 0 and k.fy > 0


@FUZZ
@given(data=values)
def test_random_intrinsics_json_files(workdir, data):
    try:
        text = json.dumps(data, allow_nan=True)
    except (ValueError, TypeError):
        return
    try:
        parse_intrinsics(_write(workdir, "fuzz.json", text), (48, 64))
    except IntrinsicsError:
        pass



# --------------------------------------------------------------------------- point clouds


def _cloud_or_documented_error(path):
    try:
        pf = load_points(path)
    except DepthError as e:
        assert str(e).startswith(path) and "\n" not in str(e)
        return None
    assert pf.points.ndim == 2 and pf.points.shape[1] == 3 and pf.points.dtype == np.float32
    return pf


def _cloud_files() -> dict:
    """One small valid file per format (3 points), to corrupt."""
    pts = np.float32([[0.1, 0.2, 1.5], [0.0, -0.1, 1.6], [0.3, 0.0, 1.4]])
    ply = "ply\nformat {} 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    pcd = ("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 3\nHEIGHT 1\n"
           "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA {}\n")
    soa = pts.T.astype("<f4").tobytes()  # binary_compressed: the fields one after another, as 2 literal runs
    lzf = bytes([31]) + soa[:32] + bytes([len(soa) - 33]) + soa[32:]
    text = "\n".join(" ".join(repr(float(v)) for v in p) for p in pts) + "\n"
    faces = "element face 2\nproperty list uchar int vertex_indices\nelement vertex"  # faces before the vertices
    return {
        ".ply": [(ply.format("ascii") + text).encode(), ply.format("binary_little_endian").encode() + pts.tobytes(),
                 ply.format("binary_big_endian").encode() + pts.astype(">f4").tobytes(),
                 ply.format("binary_little_endian").replace("element vertex", faces).encode()
                 + b"\x03" + np.int32([0, 1, 2]).tobytes() + b"\x01" + np.int32([1]).tobytes() + pts.tobytes()],
        ".pcd": [(pcd.format("ascii") + text).encode(), pcd.format("binary").encode() + pts.tobytes(),
                 pcd.format("binary_compressed").encode() + np.uint32([len(lzf), len(soa)]).tobytes() + lzf],
        ".xyz": [text.encode()],
        ".npy": [_npy_bytes(pts), _npy_bytes(pts.reshape(1, 3, 3).astype(np.float64))],
    }


CLOUD_FILES = _cloud_files()


def test_the_cloud_fuzz_seeds_are_valid(workdir):
    for ext, files in CLOUD_FILES.items():
        for i, data in enumerate(files):
            pf = load_points(_write(workdir, f"seed{i}{ext}", data))
            assert pf.points.shape == (3, 3) and np.allclose(pf.points[0], [0.1, 0.2, 1.5]), (ext, i)


@FUZZ
@given(pick=st.tuples(st.sampled_from(sorted(CLOUD_FILES)), st.integers(0, 3)), cut=st.integers(0, 80), edit=edits)
def test_corrupted_cloud_files(workdir, pick, cut, edit):
    ext, i = pick
    seeds = CLOUD_FILES[ext]
    data = _corrupt(seeds[i % len(seeds)], edit)
    data = data[: len(data) - cut] if cut < len(data) else data
    _cloud_or_documented_error(_write(workdir, "fuzz" + ext, data))


@FUZZ
@given(raw=st.binary(max_size=300), prefix=st.sampled_from([b"", b"ply\nformat ascii 1.0\n", b"VERSION 0.7\n"]),
       ext=st.sampled_from([".ply", ".pcd", ".xyz"]))
def test_random_bytes_as_cloud_files(workdir, raw, prefix, ext):
    _cloud_or_documented_error(_write(workdir, "fuzz" + ext, prefix + raw))


@FUZZ
@given(pts=hnp.arrays(np.float64, st.tuples(st.integers(0, 80), st.just(3)),
                      elements=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-2, 3))),
       near=st.floats(-1, 3), far=st.floats(-1, 10), max_points=st.integers(-1, 40), min_points=st.integers(0, 5))
def test_random_points_to_cloud(pts, near, far, max_points, min_points):
    try:
        cloud = sensor_points_to_cloud(pts, near, far, max_points, min_points=min_points)
    except DepthError as e:
        assert "\n" not in str(e)
        return
    w = np.asarray(cloud.weights)
    assert cloud.points.shape == (max_points, 3) and np.all(np.isfinite(cloud.points))
    kept = np.asarray(cloud.points)[w > 0]
    assert len(kept) >= min(min_points, max_points) and np.all((kept[:, 2] >= near) & (kept[:, 2] <= far))
