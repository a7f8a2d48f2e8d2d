"""What ``jaxpose view`` draws, computed without a browser (jaxpose/viewer/scene.py)."""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxpose.io.truth import TruthError
from jaxpose.viewer import scene
from jaxpose.viewer.scene import load_view, node_names

from viewer_fixtures import TRUTH, copy_inputs, demo_points, demo_result, sequence, write


def _segment_distance(p, a, b):
    t = np.clip(np.dot(p - a, b - a) / np.dot(b - a, b - a), 0, 1) if np.any(b != a) else 0.0
    return np.linalg.norm(p - (a + t * (b - a)))


# --------------------------------------------------------------------------- geometry


@pytest.mark.parametrize("start,end,radius", [((0, 0, 1), (0.3, -0.1, 1.2), 0.02), ((1, 2, 3), (1, 2, 3), 0.05),
                                              ((0, 0, 0), (0, 1, 0), 0.1)])
def test_capsule_mesh_is_a_closed_outward_surface_at_the_radius(start, end, radius):
    a, b = np.array(start, float), np.array(end, float)
    v, f = scene.capsule_mesh(a, b, radius, segments=24, rings=8)
    d = [_segment_distance(p, a, b) for p in v.astype(np.float64)]
    np.testing.assert_allclose(d, radius, rtol=1e-5)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)  # closed: each edge in two triangles
    p = v.astype(np.float64)[f]
    volume = np.sum(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2]))) / 6
    exact = np.pi * radius**2 * np.linalg.norm(b - a) + 4 / 3 * np.pi * radius**3
    assert 0.9 * exact < volume <= exact  # positive: faces point outwards; inscribed: a little less


def test_distance_to_the_model_is_zero_inside_and_the_gap_outside():
    link = scene.Link("a", None, np.zeros(3), np.zeros(3), np.array([0.0, 0.0, 1.0]), 0.1)
    pts = np.array([[0, 0, 0.5], [0.05, 0, 0.2], [0.3, 0, 0.5], [0, 0, 1.5], [0, 0.4, -0.3]])
    np.testing.assert_allclose(scene.distances_to_links(pts, [link]), [0, 0, 0.2, 0.4, 0.4], atol=1e-12)


def test_colours_run_from_dark_blue_to_yellow():
    c = scene.colormap(np.array([0.0, 0.5, 1.0, 7.0]), 0.0, 1.0)
    assert tuple(c[0]) == (68, 1, 84) and tuple(c[2]) == tuple(c[3]) == (253, 231, 37)
    pts = np.array([[0, 0, 1.0], [0, 0, 2.0], [0, 0, 1.5]])
    by_depth = scene.point_colours(pts, "depth")
    assert tuple(by_depth[0]) == (68, 1, 84) and tuple(by_depth[1]) == (253, 231, 37)
    link = scene.Link("a", None, np.zeros(3), np.array([0, 0, 1.0]), np.array([0, 0, 2.0]), 0.0)
    assert tuple(scene.point_colours(pts, "distance", [link])[0]) == (68, 1, 84)  # on the model
    with pytest.raises(ValueError):
        scene.point_colours(pts, "height")


def test_quaternions_agree_with_scipy():
    for r in Rotation.random(20, random_state=0):
        w, x, y, z = scene.wxyz_from_matrix(r.as_matrix())
        assert np.isclose(abs(np.dot([x, y, z, w], r.as_quat())), 1.0)


def test_a_camera_looking_at_a_point_sees_it_in_the_middle():
    pos, target = np.array([0.4, -0.5, 0.2]), np.array([0.0, 0.1, 1.3])
    wxyz = scene.look_at(pos, target)
    r = Rotation.from_quat([*wxyz[1:], wxyz[0]]).as_matrix()  # camera axes in the frame
    in_cam = r.T @ (target - pos)
    assert in_cam[2] > 0 and np.allclose(in_cam[:2], 0, atol=1e-9)
    assert r[:, 1] @ np.array([0, 1, 0]) > 0  # the picture's down is the frame's +y


def test_joint_frames_sit_at_the_anchors_with_x_along_the_link():
    links = scene.load_view(TRUTH).frames[0].links
    for link, (pos, wxyz) in zip(links, scene.joint_frames(links)):
        r = Rotation.from_quat([*wxyz[1:], wxyz[0]]).as_matrix()
        axis = (link.end - link.start) / np.linalg.norm(link.end - link.start)
        np.testing.assert_allclose(pos, link.origin)
        np.testing.assert_allclose(r[:, 0], axis, atol=1e-9)


def test_the_frustum_is_the_kinects_by_default():
    fov, aspect = scene.frustum(None)
    assert np.isclose(fov, 2 * np.arctan(240 / 525)) and np.isclose(aspect, 4 / 3)


# --------------------------------------------------------------------------- reading results


def test_a_result_shows_its_points_and_one_capsule_per_link(tmp_path):
    doc = demo_result()
    view = load_view(write(tmp_path / "r.json", doc))
    f = view.frames[0]
    assert [link.name for link in f.links] == [link["name"] for link in doc["links"]]
    assert len(f.points) == doc["input"]["points_used"] == len(demo_points())
    assert node_names(view) == (["/points"] + [f"/fit/{n['name']}" for n in doc["links"]]
                                + [f"/joints/{n['name']}" for n in doc["links"]] + ["/camera"])
    assert not view.notes and not view.is_sequence and view.truth is None


def test_a_truth_file_adds_its_links(tmp_path):
    view = load_view(write(tmp_path / "r.json", demo_result()), TRUTH)
    truth = json.load(open(TRUTH))["links"]
    assert [link.name for link in view.truth] == [link["name"] for link in truth]
    assert [n for n in node_names(view) if n.startswith("/truth/")] == [f"/truth/{t['name']}" for t in truth]


def test_points_of_an_older_result_are_rebuilt_from_its_input(tmp_path):
    copy_inputs(tmp_path)
    view = load_view(write(tmp_path / "r.json", demo_result(points=False)))
    np.testing.assert_allclose(view.frames[0].points, demo_points(), atol=1e-6)
    assert not view.notes


def test_a_moved_input_is_said_in_one_line_and_the_model_shown_alone(tmp_path):
    view = load_view(write(tmp_path / "r.json", demo_result(points=False)))
    assert view.frames[0].points is None and "/points" not in node_names(view)
    assert len(view.notes) == 1 and "\n" not in view.notes[0]
    assert "spider_demo.png is neither beside the result nor in the working folder" in view.notes[0]
    assert view.notes[0].endswith("showing the model alone")


def test_an_input_that_changed_is_not_used(tmp_path):
    copy_inputs(tmp_path)
    shutil.copy(tmp_path / "spider_demo_background.png", tmp_path / "spider_demo.png")
    view = load_view(write(tmp_path / "r.json", demo_result(points=False)))
    assert view.frames[0].points is None
    assert "is not the file that was fitted (its sha256 differs)" in view.notes[0]


def test_a_tracked_sequence_plays_in_track_json_order(tmp_path):
    docs = sequence(tmp_path / "seq")
    view = load_view(str(tmp_path / "seq"))
    assert view.is_sequence and view.fps == 12.5 and len(view.frames) == 5
    assert [f.frame for f in view.frames] == [0, 1, 2, 3, 4]
    assert [f.mode for f in view.frames] == ["global", "tracked", "tracked", "lost", "global"]
    assert [f.cost for f in view.frames] == [d["cost"] for d in docs]
    for f, d in zip(view.frames, docs):  # each frame its own links
        np.testing.assert_allclose(f.links[0].start, d["links"][0]["start"])
        assert len(f.points) == len(d["points"])
    assert scene.frame_caption(view, 3) == "frame 3, lost, cost 0.0230, 0.13 s"


def test_a_folder_of_fits_is_a_sequence_in_name_order(tmp_path):
    for name in ("f10", "f2", "f1"):
        write(tmp_path / f"{name}.json", demo_result(cost=float(name[1:]), max_points=100))
    write(tmp_path / "settings.json", {"not": "a result"})
    (tmp_path / "notes.json").write_text("{broken")
    view = load_view(str(tmp_path))
    assert [f.cost for f in view.frames] == [1, 2, 10] and view.fps == scene.DEFAULT_FPS


@pytest.mark.parametrize("make,message", [
    (lambda d: None, "holds no result file (a .json with a 'links' list)"),
    (lambda d: write(d / "track.json", {"frames": []}), "track.json: needs a non-empty 'frames' list"),
    (lambda d: write(d / "track.json", {"frames": [{"input": "a.png"}]}),
     "the result of frame #1 (a.png),"),
    (lambda d: (write(d / "a.json", demo_result(max_points=60)),
                write(d / "track.json", {"frames": [{"input": "a.png", "mode": "lucky"}]})),
     "frame #1: mode 'lucky' is not one of global, tracked, lost"),
])
def test_a_bad_folder_is_refused(tmp_path, make, message):
    make(tmp_path)
    with pytest.raises(TruthError, match=message.replace("(", r"\(").replace(")", r"\)").replace(".", r"\.")):
        load_view(str(tmp_path))


def test_a_truth_file_with_a_folder_is_refused(tmp_path):
    sequence(tmp_path / "seq", n=2)
    with pytest.raises(TruthError, match="a truth file goes with one result file"):
        load_view(str(tmp_path / "seq"), TRUTH)


def test_the_orbit_camera_sees_the_whole_scene(tmp_path):
    view = load_view(write(tmp_path / "r.json", demo_result()))
    f = view.frames[0]
    for az, el in ((0, 0), (35, 25), (-60, 20)):
        pos, wxyz = scene.orbit_camera(f, None, az, el, fov=0.8)
        r = Rotation.from_quat([*wxyz[1:], wxyz[0]]).as_matrix()
        cam = (f.points - pos) @ r  # camera coordinates
        assert np.all(cam[:, 2] > 0)
        half = np.tan(0.4)
        assert np.all(np.abs(cam[:, 1] / cam[:, 2]) < half) and np.all(np.abs(cam[:, 0] / cam[:, 2]) < half)
    pos, _ = scene.orbit_camera(f, None, 0, 0)
    centre, _ = scene.bounds(f)
    assert np.allclose((pos - centre)[:2], 0) and pos[2] < centre[2]  # from the sensor's side


def test_results_in_a_folder_keep_their_own_paths(tmp_path):
    os.makedirs(tmp_path / "a")
    copy_inputs(tmp_path / "a")
    path = write(tmp_path / "a" / "r.json", demo_result(points=False))
    view = load_view(path)  # found beside the result, not in the working folder
    assert view.frames[0].points is not None


def test_a_result_records_the_points_used_without_the_padding():
    from jaxpose.io.fit_result import points_table
    from jaxpose.objective import Cloud

    pts = np.array([[0.123456, -1.0, 2.0], [9.0, 9.0, 9.0], [0.5, 0.25, 1.00004]])
    table = points_table(Cloud(pts, np.array([1.0, 0.0, 1.0])))
    assert table == [[0.1235, -1.0, 2.0], [0.5, 0.25, 1.0]]  # 0.1 mm; the weight-0 padding left out


def test_a_tracked_frame_without_points_finds_its_input_from_track_json(tmp_path, monkeypatch):
    os.makedirs(tmp_path / "frames")
    copy_inputs(tmp_path / "frames")
    os.makedirs(tmp_path / "seq")
    write(tmp_path / "seq" / "spider_demo.json", demo_result(points=False))
    write(tmp_path / "seq" / "track.json", {"frames": [{"input": "frames/spider_demo.png", "mode": "global"}]})
    monkeypatch.chdir(tmp_path)  # where the track command ran
    view = load_view("seq")
    np.testing.assert_allclose(view.frames[0].points, demo_points(), atol=1e-6)
    monkeypatch.chdir(tmp_path / "seq")  # elsewhere: not found, said in one line
    assert load_view(".").frames[0].points is None
