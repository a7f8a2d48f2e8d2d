"""Robot models seen through MuJoCo's own renderer, fitted by jaxpose, scored against MuJoCo's kinematics.

Every other data set of this project is rendered by jaxpose's ray caster from the very
capsules jaxpose fits.  Here the depth images come from a renderer jaxpose did not
write (MuJoCo's OpenGL depth buffer, ``mujoco.Renderer``) and show each model's true
geometry (boxes, cylinders, ellipsoids, meshes), which jaxpose approximates by capsules
(up to ``--capsules`` per link).  The truth is the pose MuJoCo's joint values give: jaxpose's
forward kinematics of :func:`~jaxpose.io.mjcf.pose_from_qpos` (equal to MuJoCo's
``mj_kinematics``, tests/io/test_mjcf.py), moved into the camera's frame.

Per model and view: joint values drawn around ``qpos0`` (``--spread`` times half of each
range; a pose whose own geoms interpenetrate by more than 2 cm in MuJoCo's contacts, parts
that touch in the rest pose aside, is drawn again: ``--keep-self-contacts`` keeps it), a free
camera on a random orbit (elevation 15-45 degrees down, any azimuth)
framing the model, the depth buffer in millimetres with Gaussian noise of
``0.0015 z^2`` m and nothing beyond 0.4-4 m, and a second render with the model's geoms hidden as the background
image (floors and other world geoms stay in it).  The fit is ``jaxpose.fit_file``
with the default ``FitConfig`` (``--generations`` to change it).

Every view also records each link's visible fraction (MuJoCo's segmentation render: points
along the link's axis inside the image, within the sensor's range, not hidden by another body),
so the table splits the links the camera sees from the others, and the cost of the truth on
the fit's own cloud beside the found pose's: a view with a missed link is the search's failure
when the truth costs less (a better optimum exists), else the objective's.

Needs the ``mujoco`` extra and an OpenGL context (``MUJOCO_GL=egl``, the default set
here, or ``osmesa``); without one it says so and exits with status 0, so that
``make paper`` runs anywhere.

    python experiments/mujoco_views.py                   # the test fixtures' robots, 4 views each
    python experiments/mujoco_views.py --models robot.xml arm.urdf --views 8
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
import xml.etree.ElementTree as ET

if sys.platform.startswith("linux"):  # headless OpenGL; MuJoCo refuses "egl" at import elsewhere
    os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

import jaxpose as jp  # noqa: E402
from jaxpose.io.atomic import write_json  # noqa: E402
from jaxpose.io.capsules import MAX_CAPSULES  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # common.py, when imported from elsewhere
from common import COST_MARGIN, VISIBLE  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FIXTURES = os.path.join(ROOT, "tests", "fixtures")
MODELS = [os.path.join(FIXTURES, f) for f in ("ant.xml", "humanoid_lite.xml", "planar.xml", "arm7.urdf",
                                              "gripper.urdf", "quadruped.urdf")]
NOISE = 0.0015  # metres at 1 m, growing with the square of depth (a Kinect v1's order)
RANGE = (0.4, 4.0)  # metres: what the sensor measures


def load(path: str, max_capsules: int | None = None):
    """``(mujoco model, jaxpose skeleton, qpos -> jaxpose Pose)`` of an MJCF or URDF file."""
    import mujoco

    from jaxpose.io.mjcf import compile_mjcf, pose_from_qpos, skeleton_from_model

    if path.lower().endswith(".urdf"):
        # MuJoCo's URDF import fuses links on fixed joints into their parents, the root link into the
        # world (where the background render would keep it): keep every link a body of its own
        robot = ET.parse(path).getroot()
        ext = robot.find("mujoco")
        if ext is None:
            ext = ET.SubElement(robot, "mujoco")
        compiler = ext.find("compiler")
        if compiler is None:
            compiler = ET.SubElement(ext, "compiler")
        compiler.set("fusestatic", "false")
        compiler.set("strippath", "false")
        compiler.set("meshdir", compiler.get("meshdir") or os.path.dirname(os.path.abspath(path)))
        m = mujoco.MjModel.from_xml_string(ET.tostring(robot, encoding="unicode"))
        skel = jp.load_skeleton(path, max_capsules=max_capsules)
        child = {j.get("name"): j.find("child").get("link") for j in ET.parse(path).getroot().findall("joint")}

        def pose(qpos):  # the URDF root sits at MuJoCo's world origin; MuJoCo keeps the joint names
            angles = np.zeros((skel.num_links, 3), np.float32)
            for j in range(m.njnt):
                angles[skel.index(child[m.joint(j).name]), 0] = qpos[m.jnt_qposadr[j]] - m.qpos0[m.jnt_qposadr[j]]
            rest = jp.rest_pose(skel)
            return rest._replace(angles=np.asarray(angles))

        return m, skel, pose
    m = compile_mjcf(path)
    skel = skeleton_from_model(m, source=path, **({} if max_capsules is None else {"max_capsules": max_capsules}))
    return m, skel, lambda qpos: pose_from_qpos(skel, m, qpos)


FRAME_TOL = 0.05  # metres: frames@5cm
FRAME_AXIS = 0.1  # metres: the axis tips scored by frames@5cm


def frames_score(skel, fit_links, true_R, true_origin) -> float:
    """frames@5cm: the fraction of links (extra capsules of a link left out: they share its frame)
    whose frame is placed right, its origin and the tips of its three axes ``FRAME_AXIS`` out all
    within ``FRAME_TOL`` of the truth's (camera frame).  Independent of the capsules, so it compares
    fits of different capsule models of the same robot.  Strict: interchangeable limbs are not
    matched, so a fit turned onto a symmetric copy of the truth (an ant a quarter turn round, its
    legs swapped) scores 0 here while the symmetric PCP counts it right."""
    keep = [i for i, b in enumerate(skel.bodies) if b == i]

    def marks(R, o):
        R, o = np.asarray(R, np.float64)[keep], np.asarray(o, np.float64)[keep]
        return np.concatenate([o[:, None], o[:, None] + FRAME_AXIS * np.swapaxes(R, -1, -2)], 1)  # (L, 4, 3)

    err = np.linalg.norm(marks(fit_links.R_world_link, fit_links.origin) - marks(true_R, true_origin), axis=-1)
    return float(np.mean(np.all(err <= FRAME_TOL, axis=1)))


def random_qpos(m, rng, spread: float | None, root_joints: bool = True) -> np.ndarray:
    """Joint values around ``qpos0`` (clipped into range): hinges and slides normal with ``spread``
    x half their range (unlimited: half a turn, or the model's size), kept in range; balls a random
    turn of ``spread`` x 90 degrees in the mean.  ``spread=None``: uniform over the whole range
    instead, and balls a uniform rotation.  The joints of the only top-level body (a free
    joint, a planar walker's root slides and hinge) stay: they are the root pose, and the camera
    moves instead (a walker's root slid or tipped at random would sink into its floor); with
    ``root_joints=False`` (URDF files, whose root link has no joint) every joint moves."""
    import mujoco

    hinge, slide, ball = (int(t) for t in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE,
                                           mujoco.mjtJoint.mjJNT_BALL))
    q = m.qpos0.copy()
    for j in range(m.njnt):
        a, t = int(m.jnt_qposadr[j]), int(m.jnt_type[j])
        if root_joints and is_root_joint(m, j):
            continue  # the root body's joints (a planar walker's rootx/rootz/rooty) are the root pose
        if t in (hinge, slide):
            lo, hi = joint_span(m, j)
            if spread is None:
                q[a] = rng.uniform(lo, hi)
            else:
                q[a] = np.clip(np.clip(q[a], lo, hi) + spread * (hi - lo) / 2 * rng.standard_normal(), lo, hi)
        elif t == ball and spread is None:
            v = rng.standard_normal(4)
            q[a : a + 4] = v / np.linalg.norm(v)
        elif t == ball:
            axis = rng.standard_normal(3)
            angle = spread * np.pi / 2 * abs(rng.standard_normal())
            q[a : a + 4] = np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis / np.linalg.norm(axis)])
    return q


MAX_INTERPENETRATION = 0.02  # metres of contact depth in total: a drawn pose beyond it is drawn again
MAX_TRIES = 200  # draws per view at most; then the least interpenetrating one


def self_contact_depth(m, d, ignore=frozenset()) -> float:
    """Total penetration depth (metres) of MuJoCo's contacts between the model's own geoms
    (MuJoCo's collision filters apply: a model that turns self-contacts off has none), leaving
    out the geom pairs in ``ignore``."""
    import mujoco

    mujoco.mj_forward(m, d)
    total = 0.0
    for c in d.contact[: d.ncon]:
        if m.geom_bodyid[c.geom1] > 0 and m.geom_bodyid[c.geom2] > 0 and (c.geom1, c.geom2) not in ignore:
            total += max(0.0, -float(c.dist))
    return total


def rest_contacts(m) -> frozenset:
    """Geom pairs of the model that touch in its rest pose (``qpos0``): parts designed to touch."""
    import mujoco

    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    return frozenset((int(c.geom1), int(c.geom2)) for c in d.contact[: d.ncon]
                     if m.geom_bodyid[c.geom1] > 0 and m.geom_bodyid[c.geom2] > 0)


def draw_qpos(m, d, rng, spread: float | None, root_joints: bool = True, max_tries: int = MAX_TRIES,
              limit: float = MAX_INTERPENETRATION, ignore=frozenset()):
    """:func:`random_qpos` drawn again while the model's own geoms interpenetrate by more than
    ``limit`` (a pose the robot cannot take), at most ``max_tries`` draws, then the least
    interpenetrating one: ``(qpos, depth, draws)``; ``d.qpos`` is left at the chosen pose."""
    best = (None, np.inf, 0)
    for t in range(1, max_tries + 1):
        d.qpos[:] = q = random_qpos(m, rng, spread, root_joints)
        depth = self_contact_depth(m, d, ignore)
        if depth < best[1]:
            best = (q, depth, t)
        if depth <= limit:
            break
    d.qpos[:] = best[0]
    return best


def is_root_joint(m, j: int) -> bool:
    """Joint ``j`` belongs to the only top-level body (a free joint, a planar walker's root slides and hinge)."""
    top = [b for b in range(1, m.nbody) if m.body_parentid[b] == 0]
    return len(top) == 1 and m.jnt_bodyid[j] == top[0]


def joint_span(m, j: int) -> tuple[float, float]:
    """``(low, high)`` of hinge or slide ``j``: its range, or unlimited, half a turn (a slide: the
    model's size, as the MJCF importer bounds it) each way from ``qpos0``: the skeleton's range, so
    that every drawn pose is one the fit can express."""
    import mujoco

    from jaxpose.io.mjcf import _reach

    if m.jnt_limited[j]:
        lo, hi = m.jnt_range[j]
        return float(lo), float(hi)
    a = int(m.jnt_qposadr[j])
    r = np.pi if int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_HINGE) else _reach(m)
    return float(m.qpos0[a]) - r, float(m.qpos0[a]) + r


def camera_view(m, d, rng, width: int, height: int):
    """A free camera framing the model's geoms from a random orbit: ``(mjvCamera, Intrinsics)``
    (its centre and frame come from the rendered scene, :func:`render_depth`)."""
    import mujoco

    body_geoms = np.asarray(m.geom_bodyid) > 0
    centres = np.asarray(d.geom_xpos)[body_geoms]
    lookat = centres.mean(0)
    reach = float(np.max(np.linalg.norm(centres - lookat, axis=1) + np.asarray(m.geom_rbound)[body_geoms]))
    fovy = np.deg2rad(m.vis.global_.fovy)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = lookat
    cam.distance = float(np.clip(1.2 * reach / np.sin(fovy / 2), 0.8, 3.8))
    cam.azimuth = float(rng.uniform(0, 360))
    cam.elevation = float(-rng.uniform(15, 45))
    fy = (height / 2) / np.tan(fovy / 2)
    k = jp.Intrinsics(fx=float(fy), fy=float(fy), cx=(width - 1) / 2, cy=(height - 1) / 2, width=width, height=height)
    return cam, k


def render_depth(renderer, m, d, cam, hide_model: bool = False):
    """MuJoCo's depth image (metres along the optical axis, NaN where nothing is seen) and the
    camera's ``(centre, R world -> camera)`` (the mean of MuJoCo's two eye cameras)."""
    import mujoco

    opt = mujoco.MjvOption()
    opt.geomgroup[:] = 1  # every geom, as the importers model every geom (visual and collision groups)
    opt.sitegroup[:] = 0
    opt.flags[mujoco.mjtVisFlag.mjVIS_TENDON] = 0
    saved = m.geom_group.copy()
    if hide_model:  # the world's geoms (floors) in a drawn group, the model's in one that is not
        on_body = np.asarray(m.geom_bodyid) > 0
        m.geom_group[~on_body] = 0
        m.geom_group[on_body] = 5
        opt.geomgroup[5] = 0
    try:
        renderer.update_scene(d, camera=cam, scene_option=opt)
        depth = renderer.render().astype(np.float64)
    finally:
        m.geom_group[:] = saved
    eyes = renderer.scene.camera
    centre = 0.5 * (np.asarray(eyes[0].pos) + np.asarray(eyes[1].pos))
    fwd, up = np.asarray(eyes[0].forward), np.asarray(eyes[0].up)
    R = np.stack([np.cross(fwd, up), -up, fwd])
    far = 0.99 * m.vis.map.zfar * m.stat.extent
    depth[depth >= far] = np.nan
    return depth, centre, R


def link_bodies(m, skel) -> np.ndarray:
    """MuJoCo body id of every skeleton link (``body``, ``body#capsuleN``, ``body/joint``; -1: none)."""

    def body(name):
        try:
            return m.body(name.split("/")[0].split("#")[0]).id
        except KeyError:  # a link MuJoCo merged away: its visibility by depth order alone
            return -1

    return np.array([body(n) for n in skel.link_names])


def visible_fraction(start, end, radius, link_body, pixel_body, clean, k, samples: int = 9, tol: float = 0.01):
    """:func:`jaxpose.datasets.link_visibility` with MuJoCo's segmentation: a point along a link's axis is
    visible when its pixel shows the link's body, or anything not in front of it."""
    from jaxpose.camera import project

    s, e, r = (np.asarray(a, np.float64) for a in (start, end, radius))
    p = s[:, None] + np.linspace(0, 1, samples)[None, :, None] * (e - s)[:, None]
    uv = np.round(project(p, k)).astype(int)
    H, W = clean.shape
    inside = (uv[..., 0] >= 0) & (uv[..., 0] < W) & (uv[..., 1] >= 0) & (uv[..., 1] < H) & (p[..., 2] > 0)
    u, v = np.clip(uv[..., 0], 0, W - 1), np.clip(uv[..., 1], 0, H - 1)
    seen = clean[v, u]
    own = pixel_body[v, u] == np.asarray(link_body)[:, None]
    return (inside & (seen > 0) & (own | (seen >= p[..., 2] - r[:, None] - tol))).mean(1)


def segmentation_bodies(renderer, m, d, cam) -> np.ndarray:
    """The MuJoCo body seen at every pixel (-1: none or not a geom), every geom group drawn."""
    import mujoco

    opt = mujoco.MjvOption()
    opt.geomgroup[:] = 1
    opt.sitegroup[:] = 0
    opt.flags[mujoco.mjtVisFlag.mjVIS_TENDON] = 0
    renderer.enable_segmentation_rendering()
    try:
        renderer.update_scene(d, camera=cam, scene_option=opt)
        seg = renderer.render()
    finally:
        renderer.disable_segmentation_rendering()
        renderer.enable_depth_rendering()
    ids, types = seg[..., 0], seg[..., 1]
    is_geom = (types == int(mujoco.mjtObj.mjOBJ_GEOM)) & (ids >= 0)
    return np.where(is_geom, np.asarray(m.geom_bodyid)[np.clip(ids, 0, m.ngeom - 1)], -1)


def sensor(depth, rng) -> np.ndarray:
    """Noise growing with the square of depth, nothing measured outside ``RANGE`` (a Kinect v1's
    0.4-4 m), then whole millimetres (a 16-bit PNG's content, 0: no measurement)."""
    noisy = depth + NOISE * depth**2 * rng.standard_normal(depth.shape)
    seen = np.isfinite(noisy) & (depth >= RANGE[0]) & (depth <= RANGE[1])
    return np.where(seen, np.round(np.nan_to_num(noisy) * 1000), 0).astype(np.uint16)


def run_model(path: str, views: int, seed: int, spread: float, config, out_dir: str, size=(640, 480),
              plots: int = 1, max_capsules: int | None = None, max_tries: int = MAX_TRIES):
    """Render, fit and score ``views`` views of one model; one record per view, and overlay plots
    of the first ``plots`` views in ``out_dir``.  ``max_tries``: draws of a pose whose own geoms
    interpenetrate (:func:`draw_qpos`; 1: every first draw kept)."""
    import imageio.v3 as iio
    import mujoco

    from common import miss_verdict, pose_costs

    from jaxpose.kinematics import forward_kinematics
    from jaxpose.metrics import evaluate, pcp, pcp_scored
    from jaxpose.pipeline import read_observation

    m, skel, to_pose = load(path, max_capsules)
    bodies = link_bodies(m, skel)
    ignore = rest_contacts(m)
    d = mujoco.MjData(m)
    renderer = mujoco.Renderer(m, size[1], size[0])
    renderer.enable_depth_rendering()
    name = os.path.splitext(os.path.basename(path))[0]
    records = []
    for v in range(views):
        rng = np.random.default_rng([seed, v])
        # a pose whose own geoms interpenetrate is drawn again (the first draw, and so the view, as
        # before where it is free): the robot cannot take it, and the truth would pay the collision term
        _, contact, draws = draw_qpos(m, d, rng, spread, not path.lower().endswith(".urdf"),
                                      max_tries=max_tries, ignore=ignore)
        mujoco.mj_kinematics(m, d)
        cam, k = camera_view(m, d, rng, *size)
        depth, centre, R = render_depth(renderer, m, d, cam)
        background, _, _ = render_depth(renderer, m, d, cam, hide_model=True)
        pixel_body = segmentation_bodies(renderer, m, d, cam)
        measured = np.where((depth >= RANGE[0]) & (depth <= RANGE[1]), np.nan_to_num(depth), 0.0)
        image = os.path.join(out_dir, f"{name}_{v}_depth.png")
        bg = os.path.join(out_dir, f"{name}_{v}_background.png")
        iio.imwrite(image, sensor(depth, rng))
        iio.imwrite(bg, sensor(background, rng))
        links = forward_kinematics(skel, to_pose(d.qpos))
        true_start = (np.asarray(links.start, np.float64) - centre) @ R.T
        true_end = (np.asarray(links.end, np.float64) - centre) @ R.T
        true_origin = (np.asarray(links.origin, np.float64) - centre) @ R.T
        true_R = R @ np.asarray(links.R_world_link, np.float64)
        true_radius = np.asarray(links.radius, np.float64)
        # each link's visible fraction: in the image, in the sensor's range, not hidden
        visible = visible_fraction(true_start, true_end, true_radius, bodies, pixel_body, measured, k)
        options = jp.InputOptions(intrinsics=f"{k.fx},{k.fy},{k.cx},{k.cy}",
                                  background=bg if np.isfinite(background).any() else None)
        t0 = time.perf_counter()
        out = jp.fit_file(image, skel, config, seed=seed, options=options, skeleton_file=path)
        seconds = time.perf_counter() - t0
        res = {link["name"]: link for link in out.document["links"]}
        ps = np.array([res[n]["start"] for n in skel.link_names])
        pe = np.array([res[n]["end"] for n in skel.link_names])
        ev = evaluate(ps, pe, true_start, true_end, skel)
        # the links PCP misses under the symmetric matching (the one of the MPJPE), by true link
        idx = {n: i for i, n in enumerate(skel.link_names)}
        perm = [idx[ev["matching"][n]] for n in skel.link_names]
        scored = pcp_scored(true_start, true_end)
        missed = ~pcp(ps[perm], pe[perm], true_start, true_end) & scored
        # the found pose against the truth on the fit's own cloud: which of the two the objective prefers
        cloud = read_observation(image, options)[2]
        found_radius = np.asarray(out.result.links.radius, np.float64)
        (found_cost, truth_cost), _ = pose_costs(cloud, skel, config, [(ps, pe, found_radius),
                                                                       (true_start, true_end, true_radius)])
        seen = visible >= VISIBLE
        rec = {"model": name, "file": os.path.relpath(path, ROOT) if path.startswith(ROOT) else os.path.basename(path),
               "view": v, "seed": seed, "links": skel.num_links, "pcp_links": ev["pcp_links"],
               "points_used": out.document["input"]["points_used"], "cost": out.document["cost"],
               "seconds": seconds, "camera_distance": cam.distance, "elevation_deg": -cam.elevation,
               "azimuth_deg": cam.azimuth, "self_contact_m": contact, "pose_draws": draws,
               **{f"{key}": ev["symmetric"][key] for key in ev["symmetric"]},
               "pcp_strict": ev["strict"]["pcp"],
               "frames_5cm": frames_score(skel, out.result.links, true_R, true_origin),
               "misplaced": [n for n, miss in zip(skel.link_names, missed) if miss],
               "visible": [float(x) for x in visible], "scored": [bool(x) for x in scored],
               "seen_links": int(np.sum(scored & seen)), "seen_placed": int(np.sum(scored & seen & ~missed)),
               "hidden_links": int(np.sum(scored & ~seen)), "hidden_placed": int(np.sum(scored & ~seen & ~missed)),
               "found_cost": float(found_cost), "truth_cost": float(truth_cost),
               "verdict": miss_verdict(found_cost, truth_cost) if missed.any() else None}
        records.append(rec)
        if v < plots:  # the fit over the depth image, the truth dashed
            from jaxpose.viz import overlay_figure, save_figure

            truth = [{"start": a.tolist(), "end": b.tolist()} for a, b in zip(true_start, true_end)]
            fig = overlay_figure(out.depth, out.intrinsics, out.document["links"], truth=truth,
                                 title=f"{name}: MuJoCo's depth, jaxpose's fit (truth: dashed)")
            save_figure(fig, os.path.join(out_dir, f"{name}_{v}_overlay.png"))
        shown = "-" if rec["pcp"] is None else f"{100 * rec['pcp']:.0f}%"
        print(f"  {name} view {v}: PCP {shown} (seen {rec['seen_placed']}/{rec['seen_links']}, hidden "
              f"{rec['hidden_placed']}/{rec['hidden_links']}), PCP@10cm {100 * rec['pcp_10cm']:.0f}%, "
              f"frames@5cm {100 * rec['frames_5cm']:.0f}%, MPJPE {rec['mpjpe_mm']:.0f} mm, "
              f"cost found {found_cost:.4f} truth {truth_cost:.4f} -> {rec['verdict'] or 'placed'}, "
              f"{seconds:.1f} s", flush=True)
    renderer.close()
    return records


WHOLE_BODY_MISS = 0.25  # a view under this PCP is a whole-body miss (the body turned or placed wrong)


def public_model(spec: str) -> str:
    """``gymnasium:NAME.xml`` -> the MJCF file the installed ``gymnasium`` package ships
    (MIT licence; found without importing it); any other ``spec`` is a path as given."""
    if not spec.startswith("gymnasium:"):
        return spec
    import importlib.util

    found = importlib.util.find_spec("gymnasium")
    if found is None or not found.submodule_search_locations:
        raise ValueError(f"{spec}: the 'gymnasium' package is not installed (pip install gymnasium)")
    path = os.path.join(list(found.submodule_search_locations)[0], "envs", "mujoco", "assets", spec.split(":", 1)[1])
    if not os.path.exists(path):
        raise ValueError(f"{spec}: gymnasium ships no such model")
    return path


def spread_arg(text: str) -> float | None:
    """``--spread``: a fraction of half each range, or ``uniform`` (over the whole range)."""
    if text == "uniform":
        return None
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number or 'uniform', got {text!r}") from None
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return v


def summary(records):
    rows = {}
    for r in records:
        rows.setdefault(r["model"], []).append(r)
    out = []
    for name, rs in rows.items():
        pcps = [r["pcp"] for r in rs if r["pcp"] is not None]
        out.append({
            "model": name, "file": rs[0]["file"], "links": rs[0]["links"], "pcp_links": rs[0]["pcp_links"],
            "views": len(rs), "pcp": float(np.mean(pcps)) if pcps else None,
            "whole_body_misses": sum(p < WHOLE_BODY_MISS for p in pcps),
            "pcp_10cm": float(np.mean([r["pcp_10cm"] for r in rs])),
            "pck_10cm": float(np.mean([r["pck_10cm"] for r in rs])),
            "frames_5cm": float(np.mean([r["frames_5cm"] for r in rs])),
            "mpjpe_mm": float(np.median([r["mpjpe_mm"] for r in rs])),
            "seconds_median": float(np.median([r["seconds"] for r in rs])),
            **visibility_split(rs),
        })
    return out


def visibility_split(rs) -> dict:
    """Links the camera sees (visible fraction >= ``VISIBLE``) and hidden ones, placed out of scored;
    views with a missed link, and whole-body misses, by verdict (the search or the objective at fault)."""
    def total(key):
        return int(sum(r.get(key, 0) for r in rs))

    def verdicts(views):
        return {v: sum(r.get("verdict") == v for r in views) for v in ("search", "objective")}

    whole = [r for r in rs if r["pcp"] is not None and r["pcp"] < WHOLE_BODY_MISS]
    ratio = lambda a, b: total(a) / total(b) if total(b) else None  # noqa: E731
    return {"seen_links": total("seen_links"), "seen_pcp": ratio("seen_placed", "seen_links"),
            "hidden_links": total("hidden_links"), "hidden_pcp": ratio("hidden_placed", "hidden_links"),
            "missed_views": verdicts(rs), "whole_body_verdicts": verdicts(whole)}


def markdown(rows, machine: str) -> str:
    lines = ["| model | links (PCP-scored) | views | PCP | seen links: PCP (links) | hidden: PCP (links) "
             "| whole-body misses (search / objective) | views missed: search / objective "
             "| PCP@10cm | PCK@10cm | frames@5cm | MPJPE (mm, median) | s / view (median) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    pct = lambda x: "-" if x is None else f"{100 * x:.1f}%"  # noqa: E731
    for r in rows:
        wb, mv = r["whole_body_verdicts"], r["missed_views"]
        lines.append(f"| {r['model']} | {r['links']} ({r['pcp_links']}) | {r['views']} | {pct(r['pcp'])} | "
                     f"{pct(r['seen_pcp'])} ({r['seen_links']}) | {pct(r['hidden_pcp'])} ({r['hidden_links']}) | "
                     f"{r['whole_body_misses']} ({wb['search']} / {wb['objective']}) | "
                     f"{mv['search']} / {mv['objective']} | "
                     f"{100 * r['pcp_10cm']:.1f}% | {100 * r['pck_10cm']:.1f}% | {100 * r['frames_5cm']:.1f}% | "
                     f"{r['mpjpe_mm']:.0f} | "
                     f"{r['seconds_median']:.1f} |")
    return "\n".join(lines) + (f"\n\nMachine: {machine}. Symmetric scores (interchangeable links matched) but "
                                f"frames@5cm (strict; extra capsules left out); a whole-body miss: PCP under "
                                f"{100 * WHOLE_BODY_MISS:.0f}%. Seen: a link's visible fraction (in the image, "
                                f"in the sensor's range, not hidden) at least {VISIBLE}. A view missed by the "
                                f"search: its fit costs more than the truth (by {COST_MARGIN} or more) on the "
                                f"same cloud; else by the objective.\n")


def gl_problem() -> str | None:
    """Why MuJoCo cannot render here (``None``: it can)."""
    try:
        import mujoco
    except ImportError:
        return "the 'mujoco' package is not installed (pip install 'jaxpose[mujoco]')"
    except Exception as e:  # noqa: BLE001 - e.g. a MUJOCO_GL value this platform does not have
        return f"MuJoCo does not import here ({e.__class__.__name__}: {' '.join(str(e).split())[:120]})"
    try:
        m = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='.1'/></worldbody></mujoco>")
        r = mujoco.Renderer(m, 8, 8)
        r.close()
    except Exception as e:  # noqa: BLE001 - any failure to get a GL context
        return (f"MuJoCo cannot open an OpenGL context with MUJOCO_GL={os.environ.get('MUJOCO_GL')} "
                f"({e.__class__.__name__}: {' '.join(str(e).split())[:120]}); try MUJOCO_GL=osmesa")
    return None


def at_least_one(text: str) -> int:
    n = int(text)
    if n < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {n}")
    return n


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", default=MODELS,
                    help="MJCF or URDF files, or gymnasium:NAME.xml for a model the gymnasium package ships "
                         "(default: the test fixtures)")
    ap.add_argument("--views", type=int, default=4, help="views (poses and cameras) per model (default 4)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--spread", type=spread_arg, default=0.3,
                    help="joint spread, fraction of half the range, or 'uniform' over the whole range (default 0.3)")
    ap.add_argument("--generations", type=int, default=None, help="FitConfig.generations (default: automatic)")
    ap.add_argument("--capsules", type=at_least_one, default=None,
                    help="capsules per link at most (load_skeleton's max_capsules; default: its default)")
    ap.add_argument("--keep-self-contacts", action="store_true",
                    help="keep every drawn pose, also those whose own geoms interpenetrate (default: drawn again, "
                         f"up to {MAX_TRIES} times, while over {MAX_INTERPENETRATION} m)")
    ap.add_argument("--plots", type=int, default=1, help="overlay plots of the first N views per model (default 1)")
    ap.add_argument("--set", dest="settings", action="append", metavar="NAME=VALUE",
                    help="a FitConfig setting (repeatable; objective.NAME for the cost's), as hard_poses.py --set")
    ap.add_argument("--out", default=None,
                    help="folder for images, JSON and the Markdown table (default experiments/results/mujoco_views; "
                         "needed with --set)")
    args = ap.parse_args(argv)
    if args.settings and not args.out:
        ap.error("--set needs --out: the default folder holds the table of the default settings")
    args.out = args.out or os.path.join(ROOT, "experiments", "results", "mujoco_views")
    from hard_poses import config_with, parse_settings

    base = config_with(parse_settings(args.settings))  # one line for an unknown name or impossible value
    problem = gl_problem()
    if problem:
        print(f"mujoco_views: skipped: {problem}")
        return 0
    from common import machine_info  # experiments/ is on the path when run as a script
    from machine import machine_id
    from outputs import write_text

    os.makedirs(args.out, exist_ok=True)
    config = dataclasses.replace(base, generations=args.generations)
    records = []
    for path in args.models:
        print(f"{os.path.basename(path)}:", flush=True)
        try:
            records += run_model(os.path.abspath(public_model(path)), args.views, args.seed, args.spread, config,
                                 args.out, plots=args.plots, max_capsules=args.capsules,
                                 max_tries=1 if args.keep_self_contacts else MAX_TRIES)
        except (jp.JaxposeError, ValueError) as e:  # e.g. a mesh MuJoCo cannot find: the others still run
            print(f"  skipped: {' '.join(str(e).split())[:200]}", flush=True)
    rows = summary(records)
    machine = machine_id()
    write_json(os.path.join(args.out, "mujoco_views.json"),
               {"machine": machine_info(), "config": config.to_dict(), "noise": NOISE,
                "pose_draws": 1 if args.keep_self_contacts else MAX_TRIES, "max_self_contact_m": MAX_INTERPENETRATION,
                "spread": "uniform" if args.spread is None else args.spread,
                "max_capsules": MAX_CAPSULES if args.capsules is None else args.capsules,
                "summary": rows, "views": records})
    table = markdown(rows, machine)
    write_text(os.path.join(args.out, "mujoco_views.md"), table)
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
