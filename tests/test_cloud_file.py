"""Point-cloud files (``jaxpose/io/cloud_file.py``) against independent writers.

Every file here is written by this test's own code (``struct``, ``ndarray.tofile``,
text formatting, a small LZF compressor written from liblzf's format description),
not by the reader's; the points read must equal the points written.  The end-to-end
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


def test_lzf_known_stream():
    # literal "abc", then a reference of 9 bytes 3 back: it overlaps its own output
    assert lzf_decompress(b"\x02abc\xe0\x00\x02", 12) == b"abcabcabcabc"
    assert lzf_decompress(b"\x00x\x20\x00", 4) == b"xxxx"  # length 1 + 2, offset 0 + 1


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
    small = ["--skeleton", "spider", "--population", "8", "--generations", "4", "--islands", "2", "--quiet"]
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
    from jaxpose.pipeline import DepthOptions, load_cloud_observation

    t, q = np.array([1.0, 2.0, 0.5]), Rotation.from_euler("zyx", [90, 10, 0], degrees=True)
    qx, qy, qz, qw = q.as_quat()
    mm = ((q.apply(POINTS[8:].astype(float)) + t) * 1000).astype(np.float32)
    np.save(tmp_path / "mm.npy", mm)
    np.save(tmp_path / "m.npy", POINTS[8:])
    opts = DepthOptions(cloud_scale=0.001, viewpoint=f"{t[0]},{t[1]},{t[2]},{qw},{qx},{qy},{qz}", max_points=600)
    _, _, a, rec = load_cloud_observation(str(tmp_path / "mm.npy"), opts)
    _, _, b, _ = load_cloud_observation(str(tmp_path / "m.npy"), DepthOptions(max_points=600))
    assert np.allclose(a.points, b.points, atol=5e-6) and np.array_equal(a.weights, b.weights)
    assert rec["cloud_scale"] == 0.001 and rec["points_in_file"] == 492


def test_bad_clouds_raise_depth_errors(tmp_path):
    write_ply(tmp_path / "ok.ply", POINTS, "binary_little_endian")
    whole = (tmp_path / "ok.ply").read_bytes()
    (tmp_path / "cut.ply").write_bytes(whole[: len(whole) - 400])
    with pytest.raises(DepthError, match=r"ends after \d+ of 500 vertices"):
        load_points(tmp_path / "cut.ply")
    write_pcd(tmp_path / "ok.pcd", POINTS, "binary_compressed")
    whole = bytearray((tmp_path / "ok.pcd").read_bytes())
    whole[-30] ^= 0xFF
    (tmp_path / "bad.pcd").write_bytes(bytes(whole))
    with pytest.raises(DepthError, match="compressed PCD data"):
        load_points(tmp_path / "bad.pcd")
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
