"""Point-cloud files (``jaxpose/io/cloud_file.py``) against independent writers.

Every file here is written by this test's own code (``struct``, ``ndarray.tobytes``,
text formatting, a small LZF compressor written from liblzf's format description),
not by the reader's; the points read must equal the points written.  The LZF
decoder is also checked against two streams made by liblzf itself (python-lzf's
``lzf.compress``, kept here as bytes).  The end-to-end
test checks that a depth image's foreground written out as a point cloud gives the
same fit, bit for bit, as the depth image itself.
"""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxpose.camera import KINECT_V1, depth_to_cloud, depth_to_points, foreground_mask, sensor_points_to_cloud
from jaxpose.errors import DepthError
from jaxpose.io.cloud_file import is_cloud_file, load_points, lzf_decompress, parse_viewpoint, to_sensor_frame

RNG = np.random.default_rng(3)
POINTS = (RNG.normal(size=(500, 3)) * [0.3, 0.2, 0.1] + [0.0, 0.1, 1.8]).astype(np.float32)
POINTS[7] = np.nan  # a hole of an organised cloud


# --------------------------------------------------------------------------- an independent LZF compressor


def lzf_compress(data: bytes) -> bytes:
    """Greedy LZF: literal runs of at most 32 bytes, back references of 3 to 264 bytes
    at offsets 1 to 8192, found by a dictionary of the last position of each 3 bytes
    (references may overlap their own output, as the format allows)."""
    out, lit, last = bytearray(), bytearray(), {}
    i, n = 0, len(data)

    def flush():
        while lit:
            run = lit[:32]
            out.append(len(run) - 1)
            out.extend(run)
            del lit[:32]

    while i < n:
        key = data[i:i + 3]
        j = last.get(key) if len(key) == 3 else None
        if len(key) == 3:
            last[key] = i
        if j is not None and 0 < i - j <= 8192:
            k = 0
            while i + k < n and k < 264 and data[j + k] == data[i + k]:
                k += 1
            if k >= 3:
                flush()
                off, ln = i - j - 1, k - 2
                if ln < 7:
                    out.append((ln << 5) | (off >> 8))
                else:
                    out.extend([(7 << 5) | (off >> 8), ln - 7])
                out.append(off & 0xFF)
                i += k
                continue
        lit.append(data[i])
        i += 1
    flush()
    return bytes(out)


# made by liblzf (python-lzf 0.2.6, lzf.compress) from LIBLZF_TEXT and from the x, y, z
# floats of LIBLZF_POINTS one field after another (a PCD binary_compressed payload)
LIBLZF_TEXT = (b"jaxpose point cloud " * 3 + bytes(range(40)) + b"\x00" * 50 + b"xyzxyzxyz" * 4)
LIBLZF_TEXT_STREAM = (
    b"\x14jaxpose point cloud j\xe0\x1e\x13\x1f\x00\x01\x02\x03\x04\x05\x06\x07\x08\t\n\x0b\x0c\r\x0e\x0f"
    b"\x10\x11\x12\x13\x14\x15\x16\x17\x18\x19\x1a\x1b\x1c\x1d\x1e\x1f\x08 !\"#$%&'\x00\xe0(\x00\x02xyz"
    b"\xe0\x16\x02\x01yz"
)
LIBLZF_POINTS = np.stack([np.tile(np.float32([0.0, 0.25, 0.5, 0.75]), 8),
                          np.repeat(np.float32([-0.5, -0.25, 0.0, 0.25, 0.5, 0.75, 1.0, 1.25]), 4),
                          np.full(32, 1.5, np.float32)], -1)
LIBLZF_POINTS_STREAM = bytes.fromhex(
    "010000400001803e2005033f00004020034000e0640f00bf2071e002030180bee00503e00700409be0030340b7e0030340c3e003"
    "03008020d3e0030300a0200fe0030300c0200fe06f0301c03f"
)


def test_lzf_known_streams():
    # literal "abc", then a reference of 9 bytes 3 back: it overlaps its own output
    assert lzf_decompress(b"\x02abc\xe0\x00\x02", 12) == b"abcabcabcabc"
    assert lzf_decompress(b"\x00x\x20\x00", 4) == b"xxxx"  # length 1 + 2, offset 0 + 1
    assert lzf_decompress(LIBLZF_TEXT_STREAM, len(LIBLZF_TEXT)) == LIBLZF_TEXT
    assert lzf_decompress(LIBLZF_POINTS_STREAM, 384) == LIBLZF_POINTS.T.astype("<f4").tobytes()


def test_pcd_compressed_by_liblzf_with_padding(tmp_path):
    """A binary_compressed PCD as PCL writes it: a padding field ``_`` in the header,
    left out of the compressed payload."""
    n = len(LIBLZF_POINTS)
    head = (f"VERSION 0.7\nFIELDS x y z _\nSIZE 4 4 4 1\nTYPE F F F U\nCOUNT 1 1 1 4\nWIDTH 8\nHEIGHT 4\n"
            f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary_compressed\n").encode()
    sizes = struct.pack("<II", len(LIBLZF_POINTS_STREAM), 384)
    (tmp_path / "pcl.pcd").write_bytes(head + sizes + LIBLZF_POINTS_STREAM)
    assert same_points(load_points(tmp_path / "pcl.pcd").points, LIBLZF_POINTS)


@pytest.mark.parametrize("data", [
    b"", bytes(range(256)) * 3, b"a" * 1000, RNG.integers(0, 4, 5000, dtype=np.uint8).tobytes(),
    POINTS.tobytes(), np.repeat(POINTS[:50], 9, 0).tobytes(),
])
def test_lzf_round_trip(data):
    packed = lzf_compress(data)
    if len(data) > 200 and len(set(data)) < 10:
        assert len(packed) < 0.8 * len(data)  # the compressor did use back references
    assert lzf_decompress(packed, len(data)) == data


@pytest.mark.parametrize("stream,size,why", [
    (b"\x05ab", 6, "overruns"), (b"\x02abc\xe0", 12, "ends inside"), (b"\x02abc\x20\x10", 5, "outside"),
    (b"\x02abc", 5, "gives 3 bytes"),
])
def test_lzf_corrupt_streams(stream, size, why):
    with pytest.raises(ValueError, match=why):
        lzf_decompress(stream, size)


# --------------------------------------------------------------------------- writers


def write_ply(path, pts, fmt="binary_little_endian", faces_first=False):
    """Vertices with x, y, z among other properties; a face element before or after them."""
    n = len(pts)
    colour = (np.arange(n) % 256).astype(np.uint8)
    face = "element face 2\nproperty list uchar int vertex_indices\n"
    head = (f"ply\nformat {fmt} 1.0\ncomment written by the test\n" + (face if faces_first else "")
            + f"element vertex {n}\nproperty double t\nproperty float x\nproperty float y\nproperty uchar red\n"
            "property float z\n" + ("" if faces_first else face) + "end_header\n")
    if fmt == "ascii":
        rows = [f"{k * 0.5} {p[0]!r} {p[1]!r} {c} {p[2]!r}" for k, (p, c) in
                enumerate(zip(pts.astype(float).tolist(), colour))]
        faces = ["3 0 1 2", "4 0 1 2 3"]
        body = "\n".join((faces if faces_first else []) + rows + ([] if faces_first else faces)) + "\n"
        path.write_bytes(head.encode() + body.encode())
        return
    e = "<" if fmt == "binary_little_endian" else ">"
    rows = b"".join(struct.pack(e + "dffBf", k * 0.5, p[0], p[1], c, p[2]) for k, (p, c) in enumerate(zip(pts, colour)))
    faces = struct.pack(e + "B3i", 3, 0, 1, 2) + struct.pack(e + "B4i", 4, 0, 1, 2, 3)
    path.write_bytes(head.encode() + (faces + rows if faces_first else rows + faces))


def write_pcd(path, pts, data="binary", viewpoint="0 0 0 1 0 0 0"):
    """Fields x y z, a packed rgb float, and a 3-count normal; PCD v0.7."""
    n = len(pts)
    rgb = np.arange(n, dtype=np.float32)
    normal = np.tile(np.float32([0, 0, 1]), (n, 1))
    head = ("# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y rgb z normal\nSIZE 4 4 4 4 4\n"
            f"TYPE F F F F F\nCOUNT 1 1 1 1 3\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT {viewpoint}\nPOINTS {n}\nDATA {data}\n")
    cols = [pts[:, 0], pts[:, 1], rgb, pts[:, 2], normal]
    if data == "ascii":
        body = "\n".join(" ".join(repr(float(v)) for v in np.hstack([c.reshape(n, -1)[i] for c in cols]))
                         for i in range(n)) + "\n"
        path.write_bytes(head.encode() + body.encode())
    elif data == "binary":
        path.write_bytes(head.encode() + np.hstack([c.reshape(n, -1) for c in cols]).astype("<f4").tobytes())
    else:  # binary_compressed: each field's values one after another, then LZF
        raw = b"".join(np.ascontiguousarray(c, "<f4").tobytes() for c in cols)
        packed = lzf_compress(raw)
        path.write_bytes(head.encode() + struct.pack("<II", len(packed), len(raw)) + packed)


def same_points(a, b):
    return a.shape == b.shape and np.array_equal(a, b, equal_nan=True)


# --------------------------------------------------------------------------- readers


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
@pytest.mark.parametrize("faces_first", [False, True])
def test_ply(tmp_path, fmt, faces_first):
    write_ply(tmp_path / "c.ply", POINTS, fmt, faces_first)
    pf = load_points(tmp_path / "c.ply")
    assert pf.format == f"ply {fmt}" and pf.viewpoint == (0, 0, 0, 1, 0, 0, 0)
    assert same_points(pf.points, POINTS)


@pytest.mark.parametrize("data", ["ascii", "binary", "binary_compressed"])
def test_pcd(tmp_path, data):
    write_pcd(tmp_path / "c.pcd", POINTS, data)
    pf = load_points(tmp_path / "c.pcd")
    assert pf.format == f"pcd {data}"
    assert same_points(pf.points, POINTS)


def test_header_quirks(tmp_path):
    """Comments that look like keywords, CRLF line ends, blank lines in ascii data."""
    pcd = ("# .PCD v0.7\r\n# DATA ascii is below\r\nVERSION 0.7\r\nFIELDS x y z\r\nSIZE 4 4 4\r\nTYPE F F F\r\n"
           "WIDTH 2\r\nHEIGHT 1\r\nPOINTS 2\r\nDATA ascii\r\n1 2 3\r\n\r\n4 5 6\r\n")
    (tmp_path / "q.pcd").write_bytes(pcd.encode())
    assert same_points(load_points(tmp_path / "q.pcd").points, np.float32([[1, 2, 3], [4, 5, 6]]))
    ply = ("ply\r\nformat ascii 1.0\r\ncomment the end_header comes later\r\nelement vertex 1\r\n"
           "property float x\r\nproperty float y\r\nproperty float z\r\nend_header\r\n7 8 9\r\n")
    (tmp_path / "q.ply").write_bytes(ply.encode())
    assert same_points(load_points(tmp_path / "q.ply").points, np.float32([[7, 8, 9]]))


def test_xyz_and_npy(tmp_path):
    lines = ["# x y z r g b"] + [f"{p[0]!r}\t{p[1]!r} {p[2]!r} 1 2 3" for p in POINTS.astype(float).tolist()]
    (tmp_path / "c.xyz").write_text("\n".join(lines[:100] + [""] + lines[100:]) + "\n")
    assert same_points(load_points(tmp_path / "c.xyz").points, POINTS)
    np.save(tmp_path / "flat.npy", POINTS.astype(np.float64))
    np.save(tmp_path / "organised.npy", POINTS.reshape(20, 25, 3))
    for name in ("flat.npy", "organised.npy"):
        assert is_cloud_file(tmp_path / name)
        assert same_points(load_points(tmp_path / name).points, POINTS)
    np.save(tmp_path / "depth.npy", np.ones((4, 5), np.float32))
    assert not is_cloud_file(tmp_path / "depth.npy")


def test_pcd_viewpoint_moves_the_points_into_the_sensor_frame(tmp_path):
    t, q = np.array([0.5, -1.0, 2.0]), Rotation.from_euler("xyz", [30, -20, 70], degrees=True)
    qx, qy, qz, qw = q.as_quat()
    world = q.apply(POINTS[8:].astype(float)) + t  # the sensor-frame points, seen from the cloud's frame
    write_pcd(tmp_path / "w.pcd", world.astype(np.float32), "binary", f"{t[0]} {t[1]} {t[2]} {qw} {qx} {qy} {qz}")
    pf = load_points(tmp_path / "w.pcd")
    assert np.allclose(pf.viewpoint, [*t, qw, qx, qy, qz])
    back = to_sensor_frame(pf.points, pf.viewpoint)
    assert np.allclose(back, POINTS[8:], atol=2e-6)
    assert parse_viewpoint(f"{t[0]},{t[1]},{t[2]},{2 * qw},{2 * qx},{2 * qy},{2 * qz}") == pytest.approx(pf.viewpoint)


def test_sensor_points_give_the_depth_images_cloud():
    """A depth image's foreground, as points, gives the very cloud the image gives."""
    depth = np.full((120, 160), np.nan, np.float32)
    depth[30:90, 40:120] = np.linspace(1.5, 2.5, 80, dtype=np.float32)
    depth[0:5, 0:5] = 9.0  # beyond far
    k = KINECT_V1._replace(fx=130.0, fy=130.0, cx=79.5, cy=59.5, width=160, height=120)
    pts, _ = depth_to_points(depth, k)
    fg = pts[foreground_mask(depth, 0.3, 8.0, None, 0.05).reshape(-1)].astype(np.float32)
    shuffled_in = np.concatenate([fg, np.full((3, 3), np.nan, np.float32), [[0, 0, 9.0]]]).astype(np.float32)
    a = depth_to_cloud(depth, k, max_points=256, seed=4)
    b = sensor_points_to_cloud(shuffled_in, max_points=256, seed=4)
    assert np.array_equal(a.points, b.points) and np.array_equal(a.weights, b.weights)


# --------------------------------------------------------------------------- end to end


def test_fit_of_a_cloud_file_equals_the_fit_of_its_depth_image(tmp_path, capsys):
    """``jaxpose fit cloud.ply`` (the demo image's foreground, written as points) gives
    the same result, bit for bit, as ``jaxpose fit`` of the depth image."""
    import jaxpose.cli as cli
    from jaxpose.demo import DATA
    from jaxpose.io.depth_file import load_depth

    DEMO_DEPTH, DEMO_BACKGROUND = f"{DATA}/spider_demo.png", f"{DATA}/spider_demo_background.png"

    depth, background = load_depth(DEMO_DEPTH), load_depth(DEMO_BACKGROUND)
    pts, _ = depth_to_points(depth, KINECT_V1)
    fg = pts[foreground_mask(depth, 0.3, 8.0, background, 0.05).reshape(-1)].astype(np.float32)
    write_ply(tmp_path / "fg.ply", fg)
    # the input path is under test, not the search: one short search
    small = ["--skeleton", "spider", "--population", "8", "--generations", "4", "--islands", "2", "--quiet",
             "--one-search", "--turns", "0", "--limb-sweep", "0", "--pivot-sweep", "0"]
    assert cli.main(["fit", str(DEMO_DEPTH), "--background", str(DEMO_BACKGROUND),
                     "--out", str(tmp_path / "d.json")] + small) == 0
    assert cli.main(["fit", str(tmp_path / "fg.ply"), "--out", str(tmp_path / "c.json"),
                     "--plot", str(tmp_path / "c.png")] + small) == 0
    d, c = (json.loads((tmp_path / f).read_text()) for f in ("d.json", "c.json"))
    assert c["genome"] == d["genome"] and c["links"] == d["links"] and c["cost"] == d["cost"]
    assert c["input"]["cloud_format"] == "ply binary_little_endian"
    assert c["input"]["points_in_file"] == len(fg) and c["input"]["points_used"] == d["input"]["points_used"]
    assert c["frame"].startswith("sensor")
    assert (tmp_path / "c.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cloud_scale_and_viewpoint_options(tmp_path):
    """A cloud in millimetres in a rotated frame, with --cloud-scale and --viewpoint,
    gives the points of the same cloud in metres in the sensor's frame."""
    from jaxpose.pipeline import InputOptions, load_cloud_observation

    t, q = np.array([1000.0, 2000.0, 500.0]), Rotation.from_euler("zyx", [90, 10, 0], degrees=True)
    qx, qy, qz, qw = q.as_quat()
    mm = (q.apply(POINTS[8:].astype(float) * 1000) + t).astype(np.float32)  # the sensor at t (mm), turned by q
    np.save(tmp_path / "mm.npy", mm)
    write_pcd(tmp_path / "mm.pcd", mm, "binary", f"{t[0]} {t[1]} {t[2]} {qw} {qx} {qy} {qz}")
    np.save(tmp_path / "m.npy", POINTS[8:])
    _, _, b, _ = load_cloud_observation(str(tmp_path / "m.npy"), InputOptions(max_points=600))
    opts = InputOptions(cloud_scale=0.001, viewpoint=f"{t[0]},{t[1]},{t[2]},{qw},{qx},{qy},{qz}", max_points=600)
    for name, o in (("mm.npy", opts), ("mm.pcd", InputOptions(cloud_scale=0.001, max_points=600))):
        _, _, a, rec = load_cloud_observation(str(tmp_path / name), o)
        assert np.allclose(a.points, b.points, atol=5e-6) and np.array_equal(a.weights, b.weights), name
        assert rec["cloud_scale"] == 0.001 and rec["points_in_file"] == 492
        assert rec["viewpoint"] == pytest.approx([*t, qw, qx, qy, qz])


def test_bad_clouds_raise_depth_errors(tmp_path):
    write_ply(tmp_path / "ok.ply", POINTS, "binary_little_endian")
    whole = (tmp_path / "ok.ply").read_bytes()
    (tmp_path / "cut.ply").write_bytes(whole[: len(whole) - 400])
    with pytest.raises(DepthError, match=r"ends after \d+ of 500 vertices"):
        load_points(tmp_path / "cut.ply")
    pcd = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {}\nHEIGHT 1\n{}POINTS {}\nDATA {}\n"
    cases = {  # file content -> the message
        pcd.format(1, "", 1, "binary_compressed").encode() + b"\x03\0\0\0\x0c\0\0\0\x20\x05\x00":
            "corrupt .a back reference points outside",
        pcd.format(10**7, "", 10**7, "binary_compressed").encode() + b"\x03\0\0\0\x00\x0e\x27\x07\x20\x05\x00":
            r"corrupt \(3 bytes cannot hold",
        pcd.format(2, "VIEWPOINT 0 0 0 0 0 0 0\n", 2, "ascii").encode() + b"1 2 3\n4 5 6\n": "quaternion .* is zero",
        pcd.format(2, "", 3, "ascii").encode(): "POINTS 3 but WIDTH x HEIGHT = 2 x 1",
        pcd.format(1, "WIDTH\n", 1, "ascii").encode(): "WIDTH line has no value",
        pcd.format(1, "", 1, "ascii").replace("COUNT 1 1 1", "COUNT 1 -1 1").encode(): "COUNT must lie within",
        b"ply\nformat binary_little_endian 1.0\nelement face 1\nproperty list char int v\nelement vertex 1\n"
        b"property float x\nproperty float y\nproperty float z\nend_header\n\xff" + bytes(12): "negative length -1",
        b"ply\nformat ascii 1.0\nelement face 1\nproperty list float int v\nend_header\n": "integer type",
        b"ply\nformat binary_little_endian 1.0\nelement face 100000000\nproperty list uchar int v\nelement vertex 1\n"
        b"property float x\nproperty float y\nproperty float z\nend_header\n\x03" + bytes(20): "ends inside",
    }
    for i, (data, message) in enumerate(cases.items()):
        f = tmp_path / f"bad{i}{'.ply' if data.startswith(b'ply') else '.pcd'}"
        f.write_bytes(data)
        with pytest.raises(DepthError, match=message):
            load_points(f)
    with pytest.raises(DepthError, match="all lie within 1 mm"):
        sensor_points_to_cloud(np.ones((100, 3), np.float32))
    with pytest.raises(DepthError, match="no point"):
        sensor_points_to_cloud(np.full((100, 3), np.nan, np.float32))


def test_cloud_view_shows_every_point_from_the_sensor():
    """The plot's view: every point projects into the image (with the returned
    intrinsics), and its pixel holds that point's depth or a nearer one."""
    from jaxpose.camera import cloud_view, project

    pts = POINTS[np.all(np.isfinite(POINTS), -1)]
    depth, k = cloud_view(pts, 320, 240)
    assert depth.shape == (240, 320) and (k.width, k.height) == (320, 240) and k.fx == k.fy
    uv = np.round(project(pts, k)).astype(int)
    assert np.all((uv >= 0) & (uv < [320, 240]))
    assert np.all(depth[uv[:, 1], uv[:, 0]] <= pts[:, 2] + 1e-6)
    assert np.isfinite(depth).sum() >= len(np.unique(uv, axis=0))


def test_render_writes_the_depth_image_as_a_cloud(tmp_path):
    """``jaxpose render --cloud``: every measured pixel of the written image, as points."""
    import jaxpose.cli as cli
    from jaxpose.io.depth_file import load_depth, parse_intrinsics

    assert cli.main(["render", "--skeleton", "spider", "--size", "160x120", "--floor", "--out", str(tmp_path / "d.png"),
                     "--truth", str(tmp_path / "t.json"), "--cloud", str(tmp_path / "d.ply")]) == 0
    depth = load_depth(tmp_path / "d.png")
    pts, valid = depth_to_points(depth, parse_intrinsics(str(tmp_path / "t.json"), depth.shape))
    pf = load_points(tmp_path / "d.ply")
    assert pf.format == "ply binary_little_endian" and valid.sum() > 1000
    assert same_points(pf.points, pts[valid].astype(np.float32))


def test_an_opengl_cloud_is_named_and_turned_by_the_documented_viewpoint(tmp_path):
    """A cloud in the OpenGL convention (y up, z towards the viewer) lies behind our
    sensor: the error says which --viewpoint turns it, and that viewpoint gives the
    very cloud of the same points in our convention."""
    from jaxpose.pipeline import InputOptions, load_cloud_observation

    ours = POINTS[8:]
    np.save(tmp_path / "cv.npy", ours)
    np.save(tmp_path / "gl.npy", ours * np.float32([1, -1, -1]))
    with pytest.raises(DepthError, match=r"OpenGL convention .* --viewpoint 0,0,0,0,1,0,0"):
        load_cloud_observation(str(tmp_path / "gl.npy"))
    a = load_cloud_observation(str(tmp_path / "gl.npy"), InputOptions(viewpoint="0,0,0,0,1,0,0"))[2]
    b = load_cloud_observation(str(tmp_path / "cv.npy"))[2]
    assert np.array_equal(a.points, b.points) and np.array_equal(a.weights, b.weights)
