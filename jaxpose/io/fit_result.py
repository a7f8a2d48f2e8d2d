"""The ``result.json`` written by ``jaxpose fit`` (schema: docs/result_json.md).

Every number except those under ``"timing"`` is bit-identical for the same
inputs, seed and config on CPU (not with a time budget: the generations run
depend on the machine's speed).
"""

from __future__ import annotations

import hashlib
import platform
from importlib import metadata

import numpy as np

from ..skeleton import Skeleton
from .truth import pose_dict

SCHEMA_VERSION = 1


def file_sha256(path: str | None) -> str | None:
    if path is None:
        return None
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def package_versions() -> dict:
    out = {"python": platform.python_version()}
    for p in ("jaxpose", "jax", "jaxlib", "evosax", "optax", "numpy", "imageio"):
        try:
            out[p] = metadata.version(p)
        except metadata.PackageNotFoundError:
            out[p] = None
    return out


def links_table(skel: Skeleton, links) -> list[dict]:
    """Every link by name with its parent, joint anchor, capsule end points and radius."""
    origin, start, end, radius = (np.asarray(a, np.float64)
                                  for a in (links.origin, links.start, links.end, links.radius))
    return [
        {
            "name": n,
            "parent": skel.link_names[p] if p >= 0 else None,
            "origin": origin[i].tolist(),
            "start": start[i].tolist(),
            "end": end[i].tolist(),
            "radius": float(radius[i]),
        }
        for i, (n, p) in enumerate(zip(skel.link_names, skel.parents))
    ]


def params_table(skel: Skeleton, pose) -> dict:
    """The fitted parameters by name (the same schema as a truth file's pose)."""
    return pose_dict(skel, pose)


def hypotheses_table(skel: Skeleton, hyp) -> list[dict]:
    """The best distinct poses, cheapest first (the first is the document's own answer):
    each one's cost, links and parameters."""
    out = []
    for i in range(int(np.shape(hyp.cost)[0])):
        take = lambda tree: type(tree)(*(np.asarray(x)[i] for x in tree))  # noqa: E731
        out.append({"cost": float(hyp.cost[i]), "links": links_table(skel, take(hyp.links)),
                    "params": params_table(skel, take(hyp.pose))})
    return out


POINTS_DECIMALS = 4  # the points used are recorded to 0.1 mm


def points_table(cloud) -> list[list[float]]:
    """The points a fit used (the cloud's points of positive weight, padding left out), in
    metres rounded to :data:`POINTS_DECIMALS` places: what ``jaxpose view`` shows."""
    pts = np.asarray(cloud.points, np.float64)[np.asarray(cloud.weights) > 0]
    return np.round(pts, POINTS_DECIMALS).tolist()


def result_document(skel: Skeleton, skeleton_file: str | None, result, config, seed: int, inputs: dict,
                    cloud=None) -> dict:
    """Assemble the JSON document of one fit (plain Python types); with ``cloud``, the
    points used under ``"points"`` (:func:`points_table`)."""
    return {
        "schema": SCHEMA_VERSION,
        "skeleton": {
            "name": skel.name, "file": skeleton_file, "sha256": file_sha256(skeleton_file) if skeleton_file else None,
            "num_links": skel.num_links, "dof": skel.num_dof,
        },
        "input": inputs,
        "algorithm": config.algorithm,
        "config": config.to_dict(),
        "seed": int(seed),
        "frame": "camera (x right, y down, z forward), metres",
        "links": links_table(skel, result.links),
        "params": params_table(skel, result.pose),
        "genome": np.asarray(result.genome, np.float64).tolist(),
        "cost": float(result.cost),
        "cost_history": np.asarray(result.history, np.float64).tolist(),
        "evaluations": {
            "objective": int(result.objective_evaluations),
            "gradient": int(result.gradient_evaluations),
            "point_to_capsule_distances": float(result.distance_evaluations),
        },
        **({"hypotheses": hypotheses_table(skel, result.hypotheses)} if result.hypotheses is not None else {}),
        **({"points": points_table(cloud)} if cloud is not None else {}),
        "versions": package_versions(),
        "timing": {"wall_seconds": float(result.wall_time)},
    }
