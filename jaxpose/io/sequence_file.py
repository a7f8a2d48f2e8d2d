"""A rendered motion sequence on disk (``jaxpose render --sequence``, ``make data``)::

    <folder>/depth/frame_00000.png ...   depth per frame (16-bit PNG, millimetres)
    <folder>/background.png              the scene without the subject
    <folder>/truth/frame_00000.json ...  the truth per frame (``jaxpose render --truth``'s
                                         format; ``"absent": true`` and no links when
                                         the subject is out of view)
    <folder>/index.json                  the sequence: frames, camera, motion, seed

``jaxpose track <folder>/depth --background <folder>/background.png`` tracks it.
"""

from __future__ import annotations

import dataclasses
import os

from .atomic import write_json
from .depth_file import save_depth_png
from .truth import truth_dict


def write_sequence(folder: str, skel, seq, skeleton_file: str | None = None, sensor=None) -> dict:
    """Write :class:`~jaxpose.sequences.Sequence` ``seq`` to ``folder``; returns the index."""
    for sub in ("depth", "truth"):
        os.makedirs(os.path.join(folder, sub), exist_ok=True)
    save_depth_png(os.path.join(folder, "background.png"), seq.background)
    k = seq.intrinsics
    frames = []
    for i, (view, depth) in enumerate(zip(seq.views, seq.depths)):
        name = f"frame_{i:05d}"
        save_depth_png(os.path.join(folder, "depth", name + ".png"), depth)
        image = os.path.join("..", "depth", name + ".png")
        if view is None:
            truth = {"format": "jaxpose-truth", "version": 1, "absent": True, "links": [], "image": image,
                     "skeleton": {"name": skel.name, "file": skeleton_file}, "meta": {"frame": i}}
        else:
            truth = truth_dict(skel, view, skeleton_file, image, os.path.join("..", "background.png"), sensor,
                               {"frame": i, "sequence": seq.name})
        write_json(os.path.join(folder, "truth", name + ".json"), truth)
        frames.append({"frame": i, "image": f"depth/{name}.png", "truth": f"truth/{name}.json",
                       "absent": view is None})
    index = {
        "sequence": seq.name,
        "skeleton": {"name": skel.name, "file": skeleton_file},
        "intrinsics": {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "width": k.width, "height": k.height},
        "T_cam_world": [list(map(float, r)) for r in seq.T_cam_world],
        "depth_scale": 0.001,
        "background": "background.png",
        "sensor": dataclasses.asdict(sensor) if sensor is not None else None,
        **seq.meta,
        "frames_list": frames,
    }
    write_json(os.path.join(folder, "index.json"), index)
    return index
