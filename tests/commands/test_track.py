"""``jaxpose track``: inputs (files, a folder, a .npy stack), the per-frame documents and
track.json, the video, bad input (one line, exit 2, nothing written) and Ctrl-C.

The settings are tests/tracking's (the same compiled programs when run together)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from jaxpose.camera import Intrinsics
from jaxpose.cli import main

K = Intrinsics(145.0, 145.0, 79.5, 59.5, 160, 120)
SETTINGS = ["--skeleton", "spider", "--intrinsics", "145,145,79.5,59.5", "--max-points", "128", "--islands", "1",
            "--population", "16", "--generations", "25", "--no-refine", "--track-population", "12",
            "--track-generations", "3", "--track-refine-steps", "8", "--turns", "0", "--limb-sweep", "0",
            "--pivot-sweep", "0", "--quiet"]
FRAMES, GAP = 7, (3, 2)  # frames 3 and 4 without the subject


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    """A small rendered spider sequence: PNG frames in a folder, the same as a .npy stack, the background."""
    import jaxpose as jp
    from jaxpose.io.depth_file import save_depth_png
    from jaxpose.sequences import spider_sequence

    d = tmp_path_factory.mktemp("seq")
    seq = spider_sequence(jp.load_skeleton("spider"), seed=5, frames=FRAMES, gap=GAP, k=K)
    (d / "frames").mkdir()
    for i, depth in enumerate(seq.depths):
        save_depth_png(str(d / "frames" / f"f{i:03d}.png"), depth)
    save_depth_png(str(d / "background.png"), seq.background)
    np.save(d / "stack.npy", np.stack([np.round(x * 1000) / 1000 for x in seq.depths]).astype(np.float32))
    return d


def run(args, capsys=None):
    rc = main(["track", *args])
    return rc, (capsys.readouterr().err if capsys else "")


def test_a_folder_is_tracked_frame_after_frame(sequence, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    rc, _ = run([str(sequence / "frames"), "--out-dir", str(out), "--background", str(sequence / "background.png"),
                 "--video", str(out / "overlay.gif"), *SETTINGS])
    assert rc == 0
    track = json.loads((out / "track.json").read_text())
    names = [f"f{i:03d}" for i in range(FRAMES)]
    assert [f["input"] for f in track["frames"]] == [str(sequence / "frames" / (n + ".png")) for n in names]
    modes = [f["mode"] for f in track["frames"]]
    lost = list(range(GAP[0], GAP[0] + GAP[1]))
    assert modes[0] == "global" and [modes[i] for i in lost] == ["lost"] * GAP[1]
    assert modes[GAP[0] + GAP[1]] == "global"  # back: the global search
    assert all(m == "tracked" for i, m in enumerate(modes) if i not in lost and i not in (0, GAP[0] + GAP[1]))
    s = track["summary"]
    tracked = [f["wall_seconds"] for f in track["frames"] if f["mode"] == "tracked"]
    assert s["frames"] == FRAMES and s["lost_frames"] == GAP[1] and s["reinitialisations"] == 1
    assert s["median_frame_seconds"] == pytest.approx(float(np.median(tracked)))
    assert s["fps"] == pytest.approx(len(tracked) / sum(tracked))
    for i, n in enumerate(names):
        doc = json.loads((out / f"{n}.json").read_text())
        assert doc["frame"] == i and doc["tracking"] == modes[i] and doc["schema"] == 1
        assert doc["cost"] == track["frames"][i]["cost"]
        if i in lost:
            assert "links" not in doc and doc["cost"] is None and len(doc["points"]) < 50
        else:
            assert len(doc["links"]) == 8 and doc["input"]["depth"] == n + ".png"
            assert len(doc["points"]) == doc["input"]["points_used"] >= 50
    import imageio.v3 as iio

    assert iio.imread(out / "overlay.gif").shape[:3] == (FRAMES, K.height, K.width)


def test_a_stack_names_its_frames_by_number(sequence, tmp_path):
    rc, _ = run([str(sequence / "stack.npy"), "--out-dir", str(tmp_path), "--background",
                 str(sequence / "background.png"), *SETTINGS])
    assert rc == 0
    files = sorted(p.name for p in tmp_path.iterdir())
    assert files == [f"stack_{i:05d}.json" for i in range(FRAMES)] + ["track.json"]
    doc = json.loads((tmp_path / "stack_00001.json").read_text())
    assert doc["input"]["stack_frame"] == 1 and doc["input"]["depth_scale"] is None


@pytest.mark.parametrize("case, args, message", [
    ("missing", ["{seq}/frames/f000.png", "{seq}/nowhere.png"], "nowhere.png: depth file not found"),
    ("no dir", ["{seq}/frames", "--out-dir", "{tmp}/absent"], "--out-dir {tmp}/absent: not a directory"),
    ("video", ["{seq}/frames", "--video", "{tmp}/v.avi"], "--video {tmp}/v.avi: expected a .gif or .mp4 file"),
    ("population", ["{seq}/frames", "--track-population", "1"], "--track-population must be"),
    ("sweep", ["{seq}/frames", "--track-sweep", "-1"], "--track-sweep must be"),
    ("recheck", ["{seq}/frames", "--track-recheck", "-2"], "--track-recheck must be"),
    ("margin", ["{seq}/frames", "--track-recheck-margin", "1"], "--track-recheck-margin must lie in [0, 1)"),
    ("lengths", ["{seq}/frames", "--track-length-window", "0.5"], "--track-length-window must be >= 1"),
    ("turns", ["{seq}/frames", "--turns", "5"], "--turns must be"),
    ("empty folder", ["{tmp}"], "the folder holds no depth image or point cloud"),
    ("corrupt", ["{seq}/frames/f000.png", "{tmp}/bad.png"], "bad.png"),
])
def test_bad_input_is_one_line_and_writes_nothing(sequence, tmp_path, capsys, case, args, message):
    (tmp_path / "bad.png").write_bytes(b"not a png")
    out = tmp_path / "out" if case != "no dir" else None
    if out:
        out.mkdir()
    if case == "empty folder":
        (tmp_path / "bad.png").unlink()
    fill = lambda a: a.format(seq=sequence, tmp=tmp_path)  # noqa: E731
    argv = [fill(a) for a in args]
    if "--out-dir" not in argv:
        argv += ["--out-dir", str(out)]
    rc, err = run([*SETTINGS, *argv], capsys)  # the case's options last: they win
    assert rc == 2
    assert err.count("\n") == 1 and err.startswith("jaxpose: error: ") and fill(message) in err, err
    if out:
        assert list(out.iterdir()) == []


def test_ctrl_c_keeps_the_frames_written(sequence, tmp_path, monkeypatch, capsys):
    from jaxpose.tracking import Tracker

    update = Tracker.update
    calls = []

    def interrupted(self, cloud, progress=None):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return update(self, cloud, progress)

    monkeypatch.setattr(Tracker, "update", interrupted)
    rc, err = run([str(sequence / "frames"), "--out-dir", str(tmp_path), "--background",
                   str(sequence / "background.png"), *SETTINGS], capsys)
    assert rc == 130 and "interrupted" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f000.json", "f001.json", "track.json"]
    track = json.loads((tmp_path / "track.json").read_text())
    assert len(track["frames"]) == 2 and track["summary"]["interrupted"] is True
