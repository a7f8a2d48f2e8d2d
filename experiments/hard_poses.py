"""Hard poses: humanoid images in any configuration within the joint limits, and why their fits miss.

Issue 29, steps 1 and 2.  The reference humanoid set (``make_data.py``) holds natural
poses of an upright person seen from the front half at 10 degrees; these sets do not:

- ``uniform``: the shipped ``humanoid`` skeleton, every joint value uniform over its
  limits, rendered by jaxpose's ray caster (:func:`jaxpose.datasets.render_orbit`: Kinect
  v1 sensor model, a floor and 3 pieces of clutter, as the reference set);
- ``mixed``: the same, half the images (even ones) natural poses
  (:func:`jaxpose.datasets.random_pose`, the reference set's spread), half uniform;
- ``mujoco``: the MJCF humanoid ``tests/fixtures/humanoid_lite.xml`` rendered by
  MuJoCo's own renderer (``experiments/mujoco_views.py``'s functions: its depth buffer,
  noise and range), qpos uniform over the joint ranges (the free root joint stays).

Every image: the body upright within ``MAX_TILT_DEG`` (jaxpose sets; MuJoCo's root stays
upright), turned any way (random yaw and camera azimuth), seen from an elevation
uniform in 0-60 degrees, the jaxpose sets from 2-3.5 m (MuJoCo's framed as
``mujoco_views.py`` frames it).  A subject (jaxpose sets) has a global scale in
0.85-1.1 and per-limb length factors in 0.8-1.2, as the reference set's subjects.
Poses whose capsules interpenetrate by more than ``MAX_INTERPENETRATION`` in total are
drawn again (`jaxpose.datasets.self_collisions` for jaxpose's skeleton, MuJoCo's
own contacts for the MJCF model).  Each truth records every link's visible fraction
(`jaxpose.datasets.link_visibility`; for MuJoCo from its segmentation render).

Two draws, kept apart: ``tuning`` (seed 7) and ``reference`` (seed 0), written to
``data/hard_poses/<set>-<draw>/`` by ``make_data.py``'s writer.

The diagnosis (``--diagnose N``, default 16): the first N images of each set's tuning
draw fitted with the default ``FitConfig()``, seed 0; every fit scored (symmetric PCP,
frame origins within 10 cm) and, for every image under 100% PCP, the cost of the true
pose under the same objective and cloud against the found pose's: *search* failure
(found cost > truth cost + ``COST_MARGIN``) or *objective* failure (the objective
prefers the wrong pose).  Every missed link is tagged occluded (visible fraction
< 0.5), swapped (placed where a link of its symmetry orbit truly is) and/or
interpenetrating (the fit's capsule sinks into another one).  Fits are stored one
file each in ``experiments/results/runs/hard_poses/`` (a rerun skips them); the
summary goes to ``experiments/results/hard_poses/``.

    python experiments/hard_poses.py                     # render both draws, diagnose 16 tuning images per set
    python experiments/hard_poses.py --sets uniform --diagnose 4
    python experiments/hard_poses.py --diagnose 0        # only the data
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

if sys.platform.startswith("linux"):  # headless OpenGL for MuJoCo's renderer (as mujoco_views.py)
    os.environ.setdefault("MUJOCO_GL", "egl")

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
for _p in (ROOT, HERE):
    if _p not in sys.path:
        sys.path.insert(0, _p)

import jax.numpy as jnp
import numpy as np
from common import COST_MARGIN, VISIBLE, pose_costs
from common import miss_verdict as classify  # noqa: F401  (the verdict of a miss, shared with mujoco_views.py)

import jaxpose
from jaxpose import datasets as D
from jaxpose import render as R
from jaxpose.geometry import matrix_to_rpy, rpy_matrix, segment_distance
from jaxpose.metrics import link_orbits
from jaxpose.skeleton import Pose, Skeleton

SETS = ("uniform", "mixed", "mujoco")
DRAWS = {"tuning": 7, "reference": 0}
MUJOCO_MODEL = os.path.join("tests", "fixtures", "humanoid_lite.xml")
DATA_DIR = os.path.join(ROOT, "data", "hard_poses")
OUT_DIR = os.path.join(HERE, "results", "hard_poses")
RUNS_DIR = os.path.join(HERE, "results", "runs", "hard_poses")

MAX_TILT_DEG = 5.0  # the body's up axis within this many degrees of the vertical
ELEVATION_DEG = (0.0, 60.0)
DISTANCE_M = (2.0, 3.5)
SCALES = (0.85, 1.1)  # a subject's global scale (the reference set's 0.85-1.1)
LENGTH_FACTORS = (0.8, 1.2)  # per orbit of alike links, as the reference set
NATURAL_SPREAD = 0.3  # random_pose's angle_spread in the reference set
MAX_INTERPENETRATION = 0.02  # metres in total (self_collisions / MuJoCo contact depths)
MAX_TRIES = 200
CLUTTER = 3
MUJOCO_SIZE = (640, 480)

PENETRATION = 0.01  # metres: a fitted link sinking this far into others is interpenetrating
ORIGIN_TOL = 0.10  # metres
WHOLE_BODY_MISS = 0.25  # an image with PCP under this is a whole-body miss


# --------------------------------------------------------------------------- pure parts: poses


def upright_rpy(rng, yaw: float | None = None, max_tilt_deg: float = MAX_TILT_DEG) -> np.ndarray:
    """Root roll, pitch, yaw of a body turned ``yaw`` (uniform when ``None``) about the vertical and
    tipped by at most ``max_tilt_deg`` (uniform in angle) towards a uniform direction."""
    yaw = rng.uniform(-np.pi, np.pi) if yaw is None else yaw
    tilt, direction = np.deg2rad(rng.uniform(0, max_tilt_deg)), rng.uniform(-np.pi, np.pi)
    axis = np.array([np.cos(direction), np.sin(direction), 0.0])
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    tip = np.eye(3) + np.sin(tilt) * K + (1 - np.cos(tilt)) * K @ K  # Rodrigues, about a horizontal axis
    return np.asarray(matrix_to_rpy(tip @ rpy_matrix(np.array([0.0, 0.0, yaw]), xp=np), xp=np), np.float64)


def tilt_deg(rpy) -> float:
    """Angle between the body's up axis (root z) and the vertical, degrees."""
    z = rpy_matrix(np.asarray(rpy, np.float64), xp=np)[:, 2]
    return float(np.degrees(np.arccos(np.clip(z[2], -1.0, 1.0))))


def uniform_angles(skel: Skeleton, rng) -> np.ndarray:
    """Joint values ``(L, 3)`` uniform over every joint's limits (unused DOFs: their 0 limits)."""
    lo, hi = np.asarray(skel.angle_lo, np.float64), np.asarray(skel.angle_hi, np.float64)
    return lo + (hi - lo) * rng.uniform(size=lo.shape)


def subject_shape(skel: Skeleton, rng) -> tuple[float, np.ndarray]:
    """A subject's global scale and link lengths (one factor per orbit of alike links, so that left
    and right match, as :func:`jaxpose.datasets.humanoid_dataset` draws them)."""
    factor = np.ones(skel.num_links)
    for orb in link_orbits(skel):
        factor[list(orb)] = rng.uniform(*LENGTH_FACTORS)
    lengths = np.clip(np.asarray(skel.length) * factor, np.asarray(skel.length_lo), np.asarray(skel.length_hi))
    return float(rng.uniform(*SCALES)), lengths


def hard_pose(skel: Skeleton, rng, kind: str = "uniform", scale: float = 1.0, lengths=None,
              max_interpenetration: float = MAX_INTERPENETRATION, max_tries: int = MAX_TRIES):
    """A pose in the skeleton's world frame, upright within :data:`MAX_TILT_DEG`, any yaw:
    ``kind="uniform"`` joint values uniform over the limits, ``"natural"`` the reference set's
    :func:`jaxpose.datasets.random_pose`.  Poses interpenetrating by more than
    ``max_interpenetration`` (:func:`jaxpose.datasets.self_collisions`) are drawn again; after
    ``max_tries`` the least colliding one is kept.  Returns ``(pose, interpenetration, tries)``."""
    lengths = np.asarray(skel.length if lengths is None else lengths, np.float32)
    best = (None, np.inf, 0)
    for t in range(1, max(1, max_tries) + 1):
        if kind == "uniform":
            angles = uniform_angles(skel, rng)
        elif kind == "natural":
            angles = np.asarray(D.random_pose(skel, rng, angle_spread=NATURAL_SPREAD, max_tries=1).angles)
        else:
            raise ValueError(f"hard_pose: kind must be 'uniform' or 'natural', got {kind!r}")
        pose = Pose(jnp.zeros(3, jnp.float32), jnp.asarray(upright_rpy(rng), jnp.float32),
                    jnp.asarray(scale, jnp.float32), jnp.asarray(angles, jnp.float32), jnp.asarray(lengths))
        c = D.self_collisions(skel, pose)
        if c < best[1]:
            best = (pose, c, t)
        if c <= max_interpenetration:
            break
    return best[0], float(best[1]), t


def humanoid_samples(set_name: str, seed: int, count: int) -> list:
    """``count`` images of the ``uniform`` or ``mixed`` set (jaxpose's renderer), seeded by ``seed``."""
    skel = jaxpose.load_skeleton("humanoid")
    sensor = R.SensorModel()
    out = []
    for i in range(count):
        rng = np.random.default_rng([seed, 29, SETS.index(set_name), i])
        kind = "natural" if set_name == "mixed" and i % 2 == 0 else "uniform"
        scale, lengths = subject_shape(skel, rng)
        pose, collision, tries = hard_pose(skel, rng, kind, scale, lengths)
        elevation = float(rng.uniform(*ELEVATION_DEG))
        azimuth = float(rng.uniform(0, 360))
        distance = float(rng.uniform(*DISTANCE_M))
        view = D.render_orbit(skel, pose, elevation, azimuth, distance, floor=True, clutter=CLUTTER, sensor=sensor,
                              seed=int(rng.integers(2**31)))
        rpy = np.asarray(pose.root_rpy, np.float64)
        out.append(D.Sample(f"{set_name}{i:03d}", view, {
            "kind": kind, "scale": scale, "tilt_deg": tilt_deg(rpy), "yaw_deg": float(np.degrees(rpy[2])),
            "inclination_deg": elevation, "azimuth_deg": azimuth, "distance": distance,
            "interpenetration_m": collision, "pose_tries": tries}))
    return out


# --------------------------------------------------------------------------- MuJoCo's renderer


def mujoco_samples(seed: int, count: int, path: str = MUJOCO_MODEL) -> tuple[list, Skeleton, dict]:
    """``count`` images of the MJCF humanoid by MuJoCo's renderer: qpos uniform over the ranges,
    random azimuth, elevation uniform in 0-60 degrees.  Returns ``(samples, skeleton, index extra)``."""
    import mujoco
    import mujoco_views as MV

    from jaxpose.camera import Intrinsics  # noqa: F401  (View.intrinsics)
    from jaxpose.kinematics import forward_kinematics

    m, skel, to_pose = MV.load(os.path.join(ROOT, path))
    d = mujoco.MjData(m)
    renderer = mujoco.Renderer(m, MUJOCO_SIZE[1], MUJOCO_SIZE[0])
    renderer.enable_depth_rendering()
    bodies = MV.link_bodies(m, skel)
    out = []
    try:
        for i in range(count):
            rng = np.random.default_rng([seed, 29, SETS.index("mujoco"), i])
            q, collision, tries = MV.draw_qpos(m, d, rng, None, max_tries=MAX_TRIES, limit=MAX_INTERPENETRATION)
            mujoco.mj_forward(m, d)
            cam, k = MV.camera_view(m, d, rng, *MUJOCO_SIZE)
            cam.azimuth = float(rng.uniform(0, 360))
            cam.elevation = -float(rng.uniform(*ELEVATION_DEG))
            depth, centre, Rcw = MV.render_depth(renderer, m, d, cam)
            background, _, _ = MV.render_depth(renderer, m, d, cam, hide_model=True)
            pixel_body = MV.segmentation_bodies(renderer, m, d, cam)
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = Rcw, -Rcw @ centre
            pose_world = to_pose(d.qpos)
            pose_cam = R.pose_to_camera(pose_world, T)
            links = forward_kinematics(skel, pose_cam)
            start, end, radius = (np.asarray(a, np.float32) for a in (links.start, links.end, links.radius))
            clean = np.nan_to_num(depth).astype(np.float32)
            vis = MV.visible_fraction(start, end, radius, bodies, pixel_body, clean, k)
            img = MV.sensor(depth, rng).astype(np.float32) / 1000
            bg = MV.sensor(background, rng).astype(np.float32) / 1000
            view = D.View(img, bg, clean, pose_cam, pose_world, start, end, radius, vis, T, k)
            out.append(D.Sample(f"mujoco{i:03d}", view, {
                "kind": "uniform", "inclination_deg": -float(cam.elevation), "azimuth_deg": float(cam.azimuth),
                "distance": float(cam.distance), "interpenetration_m": float(collision), "pose_tries": tries,
                "qpos": np.asarray(q, np.float64).tolist()}))
    finally:
        renderer.close()
    extra = {"renderer": "mujoco.Renderer depth buffer (experiments/mujoco_views.py)",
             "mujoco_sensor": {"noise_m_at_1m": MV.NOISE, "range_m": list(MV.RANGE)}}
    return out, skel, extra


# --------------------------------------------------------------------------- writing the sets


def set_folder(set_name: str, draw: str, data_dir: str = DATA_DIR) -> str:
    return os.path.join(data_dir, f"{set_name}-{draw}")


def write_set(set_name: str, draw: str, count: int, data_dir: str = DATA_DIR) -> dict:
    from make_data import write_samples

    seed = DRAWS[draw]
    t0 = time.time()
    if set_name == "mujoco":
        samples, skel, extra = mujoco_samples(seed, count)
        return write_samples(skel, samples, set_folder(set_name, draw, data_dir), MUJOCO_MODEL, seed, None,
                             f"hard_poses/{set_name}", {**extra, "draw": draw}, t0=t0)
    samples = humanoid_samples(set_name, seed, count)
    return write_samples(jaxpose.load_skeleton("humanoid"), samples, set_folder(set_name, draw, data_dir),
                         "skeletons/humanoid.toml", seed, R.SensorModel(), f"hard_poses/{set_name}",
                         {"draw": draw}, t0=t0)


# --------------------------------------------------------------------------- pure parts: the diagnosis


def link_tags(visible: float, swapped: bool, penetration: float) -> list[str]:
    """What a misplaced link's failure looks like: ``occluded`` (less than :data:`VISIBLE` of it
    visible), ``swap`` (placed where an alike link truly is), ``interpenetrating`` (the fit's capsule
    sinks more than :data:`PENETRATION` into others); ``visible`` when none of these."""
    tags = []
    if visible < VISIBLE:
        tags.append("occluded")
    if swapped:
        tags.append("swap")
    if penetration > PENETRATION:
        tags.append("interpenetrating")
    return tags or ["visible"]


def link_penetration(skel: Skeleton, start, end, radius, margin: float = 0.8) -> np.ndarray:
    """Per link, how far (metres, summed over its pairs) its capsule sinks into others beyond what
    the collision term allows: the term's own pairs and clearances
    (:func:`jaxpose.kinematics.collision_pairs`: ``rho`` keeps the overlap of the rest pose, e.g. a
    hand resting on a thigh), link by link."""
    from jaxpose.kinematics import collision_pairs

    s, e, r = (np.asarray(a, np.float64) for a in (start, end, radius))
    pairs = collision_pairs(skel, margin)
    out = np.zeros(skel.num_links)
    if len(pairs.i):
        i, j, rho = np.asarray(pairs.i), np.asarray(pairs.j), np.asarray(pairs.rho, np.float64)
        depth = np.maximum(0.0, rho * margin * (r[i] + r[j]) - segment_distance(s[i], e[i], s[j], e[j], xp=np))
        np.add.at(out, i, depth)
        np.add.at(out, j, depth)
    return out


def swapped_links(skel: Skeleton, pred_start, pred_end, true_start, true_end) -> np.ndarray:
    """Per true link: is the predicted link misplaced (PCP) but lying (PCP) on the truth of another
    link of its orbit (a left limb where the right one is)?  Links in the same (matched) order."""
    from jaxpose.metrics import pcp

    out = np.zeros(skel.num_links, bool)
    placed = pcp(pred_start, pred_end, true_start, true_end)
    for orb in link_orbits(skel):
        for a in orb:
            for b in orb:
                if a != b and not placed[a] and pcp(pred_start[[a]], pred_end[[a]], true_start[[b]], true_end[[b]])[0]:
                    out[a] = True
    return out


def rotation_angle_deg(Ra, Rb) -> float:
    c = (np.trace(np.asarray(Ra, np.float64).T @ np.asarray(Rb, np.float64)) - 1) / 2
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


# --------------------------------------------------------------------------- fitting and scoring


def load_set(set_name: str, draw: str, data_dir: str = DATA_DIR):
    """The set as :class:`common.Dataset` (for ``common.load_image``) and its skeleton."""
    import hashlib

    import common

    folder = set_folder(set_name, draw, data_dir)
    with open(os.path.join(folder, "index.json"), "rb") as f:
        raw = f.read()
    index = json.loads(raw)
    if set_name == "mujoco":
        import mujoco_views as MV

        skel = MV.load(os.path.join(ROOT, index["skeleton"]["file"]))[1]
    else:
        skel = jaxpose.load_skeleton(index["skeleton"]["name"])
    return common.Dataset(f"{set_name}-{draw}", folder, skel, index, hashlib.sha256(raw).hexdigest()[:12])


def diagnose_image(ds, entry: dict, config, seed: int) -> dict:
    """Fit one image, score it, and weigh the found pose against the truth under the same objective."""
    import common

    from jaxpose.io.truth import read_pose
    from jaxpose.kinematics import forward_kinematics
    from jaxpose.metrics import evaluate, pcp, pcp_scored
    from jaxpose.objective import observe
    from jaxpose.search import fit_cloud
    from jaxpose.search.init import search_bounds

    skel = ds.skeleton
    config = config.for_skeleton(skel)
    img = common.load_image(ds, entry)
    res = fit_cloud(img.cloud, skel, seed, config)
    truth_path = os.path.join(ds.folder, entry["truth"])
    true_pose = read_pose(truth_path, skel)
    tl = forward_kinematics(skel, true_pose)
    ts, te = np.asarray(tl.start, np.float64), np.asarray(tl.end, np.float64)
    ps, pe = np.asarray(res.links.start, np.float64), np.asarray(res.links.end, np.float64)

    costs, terms = pose_costs(img.cloud, skel, config, [(ps, pe, res.links.radius), (ts, te, tl.radius)])
    # the truth as the search can express it: encoded in the fit's bounds (clipped) and decoded
    bounds = search_bounds(skel, observe(img.cloud, config.objective), config)
    clipped = forward_kinematics(skel, jaxpose.decode(skel, bounds, jaxpose.encode(skel, bounds, true_pose)))
    clip_dev = float(max(np.abs(np.asarray(clipped.start) - ts).max(), np.abs(np.asarray(clipped.end) - te).max()))
    clip_cost = float(pose_costs(img.cloud, skel, config, [(clipped.start, clipped.end, clipped.radius)])[0][0])

    ev = evaluate(ps, pe, ts, te, skel)
    idx = {n: i for i, n in enumerate(skel.link_names)}
    perm = np.array([idx[ev["matching"][n]] for n in skel.link_names])
    scored = pcp_scored(ts, te)
    correct = pcp(ps[perm], pe[perm], ts, te)
    missed = scored & ~correct
    frames = np.array([b == i for i, b in enumerate(skel.bodies)])
    origin_err = np.linalg.norm(np.asarray(res.links.origin, np.float64)[perm] - np.asarray(tl.origin, np.float64),
                                axis=1)
    visible = np.array([float(v) for v in _truth_visible(truth_path, skel)])
    swapped = swapped_links(skel, ps[perm], pe[perm], ts, te)
    pen = link_penetration(skel, ps, pe, np.asarray(res.links.radius), config.objective.collision_margin)[perm]
    found, truth = float(costs[0]), float(costs[1])
    pcp_value = ev["symmetric"]["pcp"]
    return {
        "set": ds.model, "image": entry["name"], "seed": seed, "kind": entry.get("kind"),
        "inclination_deg": entry.get("inclination_deg"),
        "pcp": pcp_value, "pcp_strict": ev["strict"]["pcp"], "pck_10cm": ev["symmetric"]["pck_10cm"],
        "mpjpe_mm": ev["symmetric"]["mpjpe_mm"],
        "origins_10cm": float(np.mean(origin_err[frames] <= ORIGIN_TOL)),
        "found_cost": found, "result_cost": float(res.cost), "truth_cost": truth,
        "truth_clipped_cost": clip_cost,
        "terms": {k: [float(x) for x in np.asarray(v)] for k, v in terms.items()},  # [found, truth]
        "found_links": {"start": ps.tolist(), "end": pe.tolist(), "radius": np.asarray(res.links.radius).tolist()},
        "truth_clip_deviation_m": clip_dev,
        "verdict": None if not missed.any() else classify(found, truth),
        "root_error_deg": rotation_angle_deg(np.asarray(res.links.R_world_link)[0], np.asarray(tl.R_world_link)[0]),
        "links": [{"name": n, "scored": bool(scored[i]), "correct": bool(correct[i]), "visible": float(visible[i]),
                   "swap": bool(swapped[i]), "penetration_m": float(pen[i]),
                   "origin_error_m": float(origin_err[i]), "frame": bool(frames[i]),
                   "tags": link_tags(visible[i], bool(swapped[i]), float(pen[i])) if missed[i] else []}
                  for i, n in enumerate(skel.link_names)],
        "wall_seconds": float(res.wall_time),
    }


def _truth_visible(path: str, skel: Skeleton) -> list[float]:
    with open(path) as f:
        links = {ln["name"]: ln for ln in json.load(f)["links"]}
    return [links[n].get("visible", float("nan")) for n in skel.link_names]


def summarise(records: list[dict]) -> dict:
    """Per set: accuracy (all links, links seen, links not seen), whole-body misses, and the split."""
    out = {}
    for set_name in dict.fromkeys(r["set"] for r in records):
        rs = [r for r in records if r["set"] == set_name]
        links = [ln for r in rs for ln in r["links"] if ln["scored"]]
        seen = [ln for ln in links if ln["visible"] >= VISIBLE]
        hidden = [ln for ln in links if ln["visible"] < VISIBLE]
        misses = [r for r in rs if r["verdict"]]
        split = {}
        for verdict in ("search", "objective"):
            vs = [r for r in misses if r["verdict"] == verdict]
            lost = [ln for r in vs for ln in r["links"] if ln["tags"]]
            tags = {}
            for ln in lost:
                for t in ln["tags"]:
                    tags[t] = tags.get(t, 0) + 1
            split[verdict] = {
                "images": len(vs), "links_lost": len(lost), "tags": tags,
                "whole_body": sum(r["pcp"] < WHOLE_BODY_MISS for r in vs),
                "cost_gap_median": float(np.median([r["found_cost"] - r["truth_cost"] for r in vs])) if vs else None,
                "truth_outside_bounds": sum(r["truth_clip_deviation_m"] > 0.01 for r in vs),
                "images_list": [r["image"] for r in vs],
            }
        walls = sorted(r["wall_seconds"] for r in rs)
        out[set_name] = {
            "images": len(rs),
            "pcp": float(np.mean([r["pcp"] for r in rs])),
            "origins_10cm": float(np.mean([r["origins_10cm"] for r in rs])),
            "pck_10cm": float(np.mean([r["pck_10cm"] for r in rs])),
            "visible_links": len(seen),
            "visible_pcp": float(np.mean([ln["correct"] for ln in seen])) if seen else None,
            "hidden_links": len(hidden),
            "hidden_pcp": float(np.mean([ln["correct"] for ln in hidden])) if hidden else None,
            "perfect": sum(not r["verdict"] for r in rs),
            "whole_body_misses": sum(r["pcp"] < WHOLE_BODY_MISS for r in rs),
            "misses": len(misses), "split": split,
            "seconds_median": float(np.median(walls[1:] if len(walls) > 1 else walls)),
        }
    return out


def markdown(summary: dict) -> str:
    pct = lambda x: "-" if x is None else f"{100 * x:.1f}%"
    lines = [("| set | images | PCP | origins within 10 cm | visible links (PCP) | hidden links (PCP) "
              "| perfect | whole-body misses | s / image |"), "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, s in summary.items():
        lines.append(f"| {name} | {s['images']} | {pct(s['pcp'])} | {pct(s['origins_10cm'])} | "
                     f"{pct(s['visible_pcp'])} ({s['visible_links']}) | {pct(s['hidden_pcp'])} ({s['hidden_links']}) | "
                     f"{s['perfect']} | {s['whole_body_misses']} | {s['seconds_median']:.1f} |")
    lines += ["", ("| set | misses | search failures (images / links lost / whole-body) | objective failures "
                   "(images / links lost / whole-body) | objective failures' lost links by tag |"),
              "|---|---:|---:|---:|---|"]
    for name, s in summary.items():
        sf, of = s["split"]["search"], s["split"]["objective"]
        tags = ", ".join(f"{k} {v}" for k, v in sorted(of["tags"].items())) or "-"
        lines.append(f"| {name} | {s['misses']} | {sf['images']} / {sf['links_lost']} / {sf['whole_body']} | "
                     f"{of['images']} / {of['links_lost']} / {of['whole_body']} | {tags} |")
    return "\n".join(lines) + "\n"


def stored_records(sets, count: int, seed: int = 0, draw: str = "tuning") -> list[dict]:
    """The stored diagnoses of the first ``count`` images of ``sets``' ``draw`` whatever code made
    them (the newest per image), to summarise a run without fitting again."""
    import glob

    newest: dict = {}
    for path in sorted(glob.glob(os.path.join(RUNS_DIR, "*.json")), key=os.path.getmtime):
        with open(path) as f:
            rec = json.load(f)
        name = rec["set"].rsplit("-", 1)[0]
        if name in sets and rec["set"].endswith(f"-{draw}") and rec["seed"] == seed:
            newest[(name, rec["image"])] = rec
    return [newest[(s, f"{s}{i:03d}")] for i in range(count) for s in sets if (s, f"{s}{i:03d}") in newest]


def summary_name(draw: str, config, seed: int = 0) -> str:
    """The summary's file stem: ``diagnosis`` (tuning draw, default config, seed 0), else the draw,
    the settings that differ from the default and the seed (``reference``, ``diagnosis-islands=64``,
    ``diagnosis-seed1``, ...)."""
    from jaxpose.search import FitConfig

    def flat(c):  # generations: only when set (None, the default, is resolved per skeleton)
        d = c.to_dict()
        return {**{k: v for k, v in d.items() if k not in ("objective", "generations") or
                   (k == "generations" and v is not None)},
                **{f"objective.{k}": v for k, v in d["objective"].items()}}

    default, now = flat(FitConfig()), flat(config)
    text = lambda v: ",".join(map(str, v)) if isinstance(v, (tuple, list)) else str(v)  # noqa: E731 (no spaces)
    changed = [f"{k}={text(v)}" for k, v in sorted(now.items()) if default.get(k) != v]
    stem = "diagnosis" if draw == "tuning" else draw
    return "-".join([stem, *changed, *([f"seed{seed}"] if seed else [])])


def write_summary(records: list[dict], config, seed: int, out_dir: str = OUT_DIR, draw: str = "tuning") -> dict:
    import common
    from outputs import write_text

    summary = summarise(records)
    os.makedirs(out_dir, exist_ok=True)
    stem = summary_name(draw, config, seed)
    common.write_json(os.path.join(out_dir, f"{stem}.json"),
                      {"machine": common.machine_info(), "config": config.to_dict(), "seed": seed,
                       "cost_margin": COST_MARGIN, "visible": VISIBLE, "penetration_m": PENETRATION,
                       "summary": summary, "records": records})
    write_text(os.path.join(out_dir, f"{stem}.md"), markdown(summary))
    return summary


def diagnose(sets, count: int, seed: int = 0, data_dir: str = DATA_DIR, out_dir: str = OUT_DIR,
             draw: str = "tuning", config=None) -> dict:
    """Fit and diagnose the first ``count`` images of every set's ``draw`` with ``config``
    (default ``FitConfig()``), interleaved (so that an interrupted run has as many of each);
    stored fits are reused."""
    import common
    from machine import machine_id
    from outputs import log

    from jaxpose.search import FitConfig

    config = FitConfig() if config is None else config
    store = common.RunStore(RUNS_DIR)
    data = {s: load_set(s, draw, data_dir) for s in sets}
    records = []
    for i in range(count):
        for ds in data.values():
            if i >= len(ds.entries):
                continue
            entry = ds.entries[i]
            key = common.run_key(ds.model, entry["name"], f"seed{seed}",
                                 common.run_fingerprint(ds, config.for_skeleton(ds.skeleton)))
            rec = store.get(key)
            if rec is None:
                rec = diagnose_image(ds, entry, config, seed)
                rec["machine"] = machine_id()
                store.put(key, rec)
                lost = [ln["name"] + "(" + ",".join(ln["tags"]) + ")" for ln in rec["links"] if ln["tags"]]
                log(f"{ds.model:<18} {entry['name']:<10} PCP {100 * rec['pcp']:5.1f}% origins "
                    f"{100 * rec['origins_10cm']:5.1f}%  cost found {rec['found_cost']:.4f} truth "
                    f"{rec['truth_cost']:.4f} -> {rec['verdict'] or 'placed'}  {rec['wall_seconds']:.1f} s  "
                    f"{' '.join(lost)}")
            records.append(rec)
    return write_summary(records, config, seed, out_dir, draw)


def parse_settings(items) -> dict:
    """``["islands=64", "objective.collision_weight=0"]`` -> FitConfig overrides (values as JSON)."""
    out: dict = {}
    for item in items or ():
        name, _, value = item.partition("=")
        try:
            out[name] = json.loads(value)
        except json.JSONDecodeError:
            out[name] = value
    return out


def config_with(settings: dict):
    """``FitConfig()`` with ``settings`` (``objective.<name>`` for the cost's settings); an unknown
    name or an impossible value is a ``SystemExit`` naming it."""
    import dataclasses

    from jaxpose.errors import ConfigError
    from jaxpose.objective import ObjectiveConfig
    from jaxpose.search import FitConfig

    fields = {f.name for f in dataclasses.fields(FitConfig)} - {"objective"}
    costs = {f.name for f in dataclasses.fields(ObjectiveConfig)}
    wrong = [k for k in settings if not (k in fields or (k.startswith("objective.") and k[10:] in costs))]
    if wrong:
        raise SystemExit(f"--set {wrong[0]}: not a FitConfig setting (nor objective.NAME)")
    top = {k: tuple(v) if isinstance(v, list) else v for k, v in settings.items() if "." not in k}
    obj = {k.split(".", 1)[1]: v for k, v in settings.items() if k.startswith("objective.")}
    try:
        config = dataclasses.replace(FitConfig(), **top)
        return dataclasses.replace(config, objective=dataclasses.replace(config.objective, **obj)).validate()
    except ConfigError as e:
        raise SystemExit(f"--set: {e}") from None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", nargs="+", default=list(SETS), choices=SETS)
    ap.add_argument("--images", type=int, default=32, help="images per set and draw (default 32)")
    ap.add_argument("--diagnose", type=int, default=16, help="images per set to fit and diagnose (0: none)")
    ap.add_argument("--draw", default="tuning", choices=list(DRAWS), help="the draw to diagnose (default tuning)")
    ap.add_argument("--set", dest="settings", action="append", metavar="NAME=VALUE",
                    help="a FitConfig setting for the fits (repeatable; objective.NAME for the cost's)")
    ap.add_argument("--seed", type=int, default=0, help="the fits' seed (default 0)")
    ap.add_argument("--data", default=DATA_DIR, help="folder of the sets (default data/hard_poses)")
    ap.add_argument("--out", default=OUT_DIR, help="folder of the diagnosis' summary")
    ap.add_argument("--rerender", action="store_true", help="render sets that exist already again")
    ap.add_argument("--from-store", action="store_true",
                    help="summarise the stored diagnoses of the first --diagnose images, whatever code made them")
    args = ap.parse_args(argv)
    if args.from_store:
        from jaxpose.search import FitConfig

        print(markdown(write_summary(stored_records(args.sets, args.diagnose, args.seed, args.draw), FitConfig(),
                                     args.seed, args.out, args.draw)))
        return 0
    sets = list(args.sets)
    if "mujoco" in sets:
        import mujoco_views as MV

        problem = MV.gl_problem()
        if problem:
            print(f"hard_poses: the mujoco set is skipped: {problem}")
            sets.remove("mujoco")
    for s in sets:
        for draw in DRAWS:
            folder = set_folder(s, draw, args.data)
            index = os.path.join(folder, "index.json")
            have = 0
            if os.path.exists(index):
                with open(index) as f:
                    have = len(json.load(f)["images"])
            if args.rerender or have < args.images:
                write_set(s, draw, args.images, args.data)
    if args.diagnose > 0 and sets:
        summary = diagnose(sets, args.diagnose, args.seed, args.data, args.out, args.draw,
                           config_with(parse_settings(args.settings)))
        print(markdown(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
