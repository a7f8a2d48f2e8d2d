"""Truth files (``jaxpose.io.truth``): a rendered view written and read back."""

from __future__ import annotations

import json

import numpy as np

from jaxpose.camera import Intrinsics
from jaxpose.datasets import random_pose, render_orbit
from jaxpose.io.depth_file import load_depth
from jaxpose.io.skeleton_file import load_skeleton
from jaxpose.io.truth import read_links, read_pose, write_view
from jaxpose.kinematics import forward_kinematics
from jaxpose.render import SensorModel

TINY = Intrinsics(105.0, 105.0, 79.5, 59.5, 160, 120)  # Kinect field of view at 160x120


def test_truth_round_trip(tmp_path):
    skel = load_skeleton("humanoid")
    pose = random_pose(skel, 1, max_tries=2)
    view = render_orbit(skel, pose, 10, 0, 3.0, TINY, floor=True, seed=1)
    truth = write_view(str(tmp_path / "d.png"), str(tmp_path / "t.json"), skel, view, str(tmp_path / "b.png"),
                       "skeletons/humanoid.toml", SensorModel(), {"x": 1})
    assert truth["image"] == "d.png" and truth["background"] == "b.png"
    d = load_depth(str(tmp_path / "d.png"))
    valid = view.depth > 0
    np.testing.assert_allclose(d[valid], view.depth[valid], atol=6e-4)  # millimetres
    assert np.all(np.isnan(d[~valid]))
    links = read_links(str(tmp_path / "t.json"))
    assert links.names == skel.link_names and links.skeleton_name == "humanoid"
    np.testing.assert_allclose(links.start, view.start, atol=1e-6)
    np.testing.assert_allclose(links.end, view.end, atol=1e-6)
    p = read_pose(str(tmp_path / "t.json"), skel)
    fk = forward_kinematics(skel, p)
    np.testing.assert_allclose(np.asarray(fk.end), view.end, atol=1e-5)
    pw = read_pose(str(tmp_path / "t.json"), skel, world=True)
    np.testing.assert_allclose(np.asarray(pw.angles), np.asarray(pose.angles), atol=1e-6)
    data = json.loads((tmp_path / "t.json").read_text())
    assert data["camera"]["intrinsics"]["width"] == 160 and len(data["camera"]["T_cam_world"]) == 4
