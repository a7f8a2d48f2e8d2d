"""Robot models seen through MuJoCo's own renderer, fitted by jaxpose, scored against MuJoCo's kinematics.

Every other data set of this project is rendered by jaxpose's ray caster from the very
capsules jaxpose fits.  Here the depth images come from a renderer jaxpose did not
write (MuJoCo's OpenGL depth buffer, ``mujoco.Renderer``) and show each model's true
geometry (boxes, cylinders, ellipsoids, meshes), which jaxpose approximates by capsules
(up to ``--capsules`` per link).  The truth is the pose MuJoCo's joint values give: jaxpose's
forward kinematics of :func:`~jaxpose.io.mjcf.pose_from_qpos` (equal to MuJoCo's
``mj_kinematics``, tests/io/test_mjcf.py), moved into the camera's frame.

Per model and view: joint values drawn around ``qpos0`` (``--spread`` times half of each
range), a free camera on a random orbit (elevation 15-45 degrees down, any azimuth)
framing the model, the depth buffer in millimetres with Gaussian noise of
``0.0015 z^2`` m and nothing beyond 0.4-4 m, and a second render with the model's geoms hidden as the background
image (floors and other world geoms stay in it).  The fit is ``jaxpose.fit_file``
with the default ``FitConfig`` (``--generations`` to change it).

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


def is_root_joint(m, j: int) -> bool:
    """Joint ``j`` belongs to the only top-level body (a free joint, a planar walker's root slides and hinge)."""
    top = [b for b in range(1, m.nbody) if m.body_parentid[b] == 0]
    return len(top) == 1 and m.jnt_bodyid[j] == top[0]


def joint_span(m, j: int) -> tuple[float, float]:
    """``(low, high)`` of hinge or slide ``j``: its range, or unlimited, half a turn (a slide: half the
    model's size) each way from ``qpos0``."""
    import mujoco

    if m.jnt_limited[j]:
        lo, hi = m.jnt_range[j]
        return float(lo), float(hi)
    a = int(m.jnt_qposadr[j])
    r = np.pi if int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_HINGE) else 0.5 * float(m.stat.extent)
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


def sensor(depth, rng) -> np.ndarray:
    """Noise growing with the square of depth, nothing measured outside ``RANGE`` (a Kinect v1's
    0.4-4 m), then whole millimetres (a 16-bit PNG's content, 0: no measurement)."""
    noisy = depth + NOISE * depth**2 * rng.standard_normal(depth.shape)
    seen = np.isfinite(noisy) & (depth >= RANGE[0]) & (depth <= RANGE[1])
    return np.where(seen, np.round(np.nan_to_num(noisy) * 1000), 0).astype(np.uint16)


def run_model(path: str, views: int, seed: int, spread: float, config, out_dir: str, size=(640, 480),
              plots: int = 1, max_capsules: int | None = None):
    """Render, fit and score ``views`` views of one model; one record per view, and overlay plots
    of the first ``plots`` views in ``out_dir``."""
    import imageio.v3 as iio
    import mujoco

    from jaxpose.kinematics import forward_kinematics
    from jaxpose.metrics import evaluate, pcp, pcp_scored

    m, skel, to_pose = load(path, max_capsules)
    d = mujoco.MjData(m)
    renderer = mujoco.Renderer(m, size[1], size[0])
    renderer.enable_depth_rendering()
    name = os.path.splitext(os.path.basename(path))[0]
    records = []
    for v in range(views):
        rng = np.random.default_rng([seed, v])
        d.qpos[:] = random_qpos(m, rng, spread, root_joints=not path.lower().endswith(".urdf"))
        mujoco.mj_kinematics(m, d)
        cam, k = camera_view(m, d, rng, *size)
        depth, centre, R = render_depth(renderer, m, d, cam)
        background, _, _ = render_depth(renderer, m, d, cam, hide_model=True)
        image = os.path.join(out_dir, f"{name}_{v}_depth.png")
        bg = os.path.join(out_dir, f"{name}_{v}_background.png")
        iio.imwrite(image, sensor(depth, rng))
        iio.imwrite(bg, sensor(background, rng))
        links = forward_kinematics(skel, to_pose(d.qpos))
        true_start = (np.asarray(links.start, np.float64) - centre) @ R.T
        true_end = (np.asarray(links.end, np.float64) - centre) @ R.T
        true_origin = (np.asarray(links.origin, np.float64) - centre) @ R.T
        true_R = R @ np.asarray(links.R_world_link, np.float64)
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
        missed = ~pcp(ps[perm], pe[perm], true_start, true_end) & pcp_scored(true_start, true_end)
        rec = {"model": name, "file": os.path.relpath(path, ROOT) if path.startswith(ROOT) else os.path.basename(path),
               "view": v, "seed": seed, "links": skel.num_links, "pcp_links": ev["pcp_links"],
               "points_used": out.document["input"]["points_used"], "cost": out.document["cost"],
               "seconds": seconds, "camera_distance": cam.distance, "elevation_deg": -cam.elevation,
               "azimuth_deg": cam.azimuth, **{f"{key}": ev["symmetric"][key] for key in ev["symmetric"]},
               "pcp_strict": ev["strict"]["pcp"],
               "frames_5cm": frames_score(skel, out.result.links, true_R, true_origin),
               "misplaced": [n for n, miss in zip(skel.link_names, missed) if miss]}
        records.append(rec)
        if v < plots:  # the fit over the depth image, the truth dashed
            from jaxpose.viz import overlay_figure, save_figure

            truth = [{"start": a.tolist(), "end": b.tolist()} for a, b in zip(true_start, true_end)]
            fig = overlay_figure(out.depth, out.intrinsics, out.document["links"], truth=truth,
                                 title=f"{name}: MuJoCo's depth, jaxpose's fit (truth: dashed)")
            save_figure(fig, os.path.join(out_dir, f"{name}_{v}_overlay.png"))
        shown = "-" if rec["pcp"] is None else f"{100 * rec['pcp']:.0f}%"
        print(f"  {name} view {v}: PCP {shown}, PCP@10cm {100 * rec['pcp_10cm']:.0f}%, "
              f"frames@5cm {100 * rec['frames_5cm']:.0f}%, "
              f"MPJPE {rec['mpjpe_mm']:.0f} mm, {seconds:.1f} s", flush=True)
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
        })
    return out


def markdown(rows, machine: str) -> str:
    lines = ["| model | links (PCP-scored) | views | PCP | whole-body misses | PCP@10cm | PCK@10cm | frames@5cm "
             "| MPJPE (mm, median) | s / view (median) |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        pcp = "-" if r["pcp"] is None else f"{100 * r['pcp']:.1f}%"
        lines.append(f"| {r['model']} | {r['links']} ({r['pcp_links']}) | {r['views']} | {pcp} | "
                     f"{r['whole_body_misses']} | "
                     f"{100 * r['pcp_10cm']:.1f}% | {100 * r['pck_10cm']:.1f}% | {100 * r['frames_5cm']:.1f}% | "
                     f"{r['mpjpe_mm']:.0f} | "
                     f"{r['seconds_median']:.1f} |")
    return "\n".join(lines) + (f"\n\nMachine: {machine}. Symmetric scores (interchangeable links matched) but "
                                f"frames@5cm (strict; extra capsules left out); a whole-body miss: PCP under "
                                f"{100 * WHOLE_BODY_MISS:.0f}%.\n")


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
                                 args.out, plots=args.plots, max_capsules=args.capsules)
        except (jp.JaxposeError, ValueError) as e:  # e.g. a mesh MuJoCo cannot find: the others still run
            print(f"  skipped: {' '.join(str(e).split())[:200]}", flush=True)
    rows = summary(records)
    machine = machine_id()
    write_json(os.path.join(args.out, "mujoco_views.json"),
               {"machine": machine_info(), "config": config.to_dict(), "noise": NOISE,
                "spread": "uniform" if args.spread is None else args.spread,
                "max_capsules": MAX_CAPSULES if args.capsules is None else args.capsules,
                "summary": rows, "views": records})
    table = markdown(rows, machine)
    write_text(os.path.join(args.out, "mujoco_views.md"), table)
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
