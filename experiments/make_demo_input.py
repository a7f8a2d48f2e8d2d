"""Regenerate the depth image bundled for ``make demo`` (jaxpose/data/spider_demo*).

A spider in a random natural pose (a seed not used by the data sets), seen from
35 degrees above on a floor with clutter, with the Kinect v1 sensor model; the
background image is the scene without the spider.  Deterministic.
"""

from __future__ import annotations

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from jaxpose.io.skeleton_file import load_skeleton  # noqa: E402
from jaxpose.io.truth import write_view  # noqa: E402
from jaxpose.datasets import random_pose, render_orbit  # noqa: E402

OUT = os.path.join(os.path.dirname(HERE), "jaxpose", "data")


def main() -> int:
    skel = load_skeleton("spider")
    pose = random_pose(skel, 1234, angle_spread=0.45)
    view = render_orbit(skel, pose, elevation_deg=35.0, azimuth_deg=30.0, distance=1.2, floor=True, clutter=2,
                        seed=1234)
    write_view(os.path.join(OUT, "spider_demo.png"), os.path.join(OUT, "spider_demo_truth.json"), skel, view,
               background_path=os.path.join(OUT, "spider_demo_background.png"), skeleton_file="spider",
               meta={"elevation_deg": 35.0, "azimuth_deg": 30.0, "distance": 1.2, "pose_seed": 1234})
    print(f"wrote {OUT}/spider_demo.png, spider_demo_background.png, spider_demo_truth.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
