"""Result files for the viewer's tests, made without a fit: the bundled demo's truth
links posed as a "fit", and its points taken straight from the demo image (so
every test runs in milliseconds).  ``sequence`` writes a tracked sequence's folder
as issue 28 describes it (``track.json`` and ``<input name>.json`` per frame)."""

from __future__ import annotations

import hashlib
import json
import os
import shutil

import numpy as np

import jaxpose
from jaxpose.camera import KINECT_V1, depth_to_cloud
from jaxpose.io.depth_file import load_depth

DATA = os.path.join(os.path.dirname(os.path.abspath(jaxpose.__file__)), "data")
DEMO = os.path.join(DATA, "spider_demo.png")
BACKGROUND = os.path.join(DATA, "spider_demo_background.png")
TRUTH = os.path.join(DATA, "spider_demo_truth.json")


def sha256(path):
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


def demo_points(max_points=1024) -> np.ndarray:
    """The demo's cloud as ``jaxpose fit`` samples it (background subtracted, seed 0)."""
    cloud = depth_to_cloud(load_depth(DEMO), KINECT_V1, background=load_depth(BACKGROUND), max_points=max_points)
    return np.asarray(cloud.points, np.float64)[np.asarray(cloud.weights) > 0]


def demo_result(shift=(0.0, 0.0, 0.0), points=True, cost=0.03, max_points=1024, **extra) -> dict:
    """A result document in the fit's schema: the truth's links (moved by ``shift``) and,
    with ``points``, the points used."""
    truth = json.load(open(TRUTH))
    links = []
    for link in truth["links"]:
        s, e = np.add(link["start"], shift), np.add(link["end"], shift)
        links.append({"name": link["name"], "parent": link["parent"], "origin": s.tolist(), "start": s.tolist(),
                      "end": e.tolist(), "radius": link["radius"]})
    pts = demo_points(max_points)
    doc = {
        "schema": 1, "skeleton": {"name": "spider", "file": "spider"},
        "input": {"depth": "spider_demo.png", "depth_sha256": sha256(DEMO),
                  "background": "spider_demo_background.png", "background_sha256": sha256(BACKGROUND),
                  "intrinsics": {"fx": 525.0, "fy": 525.0, "cx": 319.5, "cy": 239.5, "width": 640, "height": 480},
                  "depth_scale": 0.001, "remove_planes": 0, "plane_tolerance": 0.02, "near": 0.3, "far": 8.0,
                  "max_points": max_points, "points_used": len(pts), "sample_seed": 0},
        "frame": "camera (x right, y down, z forward), metres",
        "links": links, "cost": cost,
    }
    if points:
        doc["points"] = np.round(pts, 4).tolist()
    doc.update(extra)
    return doc


def write(path, doc) -> str:
    with open(path, "w") as f:
        json.dump(doc, f)
    return str(path)


def copy_inputs(folder) -> None:
    """The demo's image and background beside a result (as a user keeps them)."""
    shutil.copy(DEMO, os.path.join(folder, "spider_demo.png"))
    shutil.copy(BACKGROUND, os.path.join(folder, "spider_demo_background.png"))


MODES = ["global", "tracked", "tracked", "lost", "global"]


def sequence(folder, n=5, fps=12.5) -> list[dict]:
    """A tracked sequence's output folder: ``track.json`` and one result per frame, the
    frames' files named so that name order differs from frame order."""
    os.makedirs(folder, exist_ok=True)
    entries, docs = [], []
    for i in range(n):
        stem = f"take_{(n - i) * 7:03d}"  # name order reverses frame order
        doc = demo_result(shift=(0.01 * i, 0.0, 0.0), cost=0.02 + 0.001 * i, max_points=200,
                          frame=i, tracking={"mode": MODES[i % len(MODES)]})
        doc["frame"] = i  # the tracking issue's per-frame number
        write(os.path.join(folder, stem + ".json"), doc)
        docs.append(doc)
        entries.append({"input": f"frames/{stem}.png", "frame": i, "mode": MODES[i % len(MODES)],
                        "cost": doc["cost"], "wall_seconds": 0.1 + 0.01 * i})
    write(os.path.join(folder, "track.json"), {"frames": entries, "summary": {"fps": fps, "frames": n}})
    return docs
