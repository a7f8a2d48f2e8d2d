"""Robot files tracked through a motion rendered by MuJoCo's own renderer (``make paper``).

Every sequence of ``jaxpose.sequences`` is drawn by jaxpose's ray caster from the
capsules jaxpose fits.  Here the frames come from MuJoCo (``mujoco.Renderer``'s depth
buffer, the models' true geoms and meshes, the sensor model of ``mujoco_views.py``),
and the truth is MuJoCo's joint values through jaxpose's forward kinematics (equal
to MuJoCo's, tests/io/test_mjcf.py).

Per model: joint values around ``qpos0`` (``--spread`` of half each range, as
``mujoco_views.py``), then every hinge and slide joint follows two sines (0.25-0.8 Hz,
amplitudes ``--amplitude`` of half its range), clipped to its range, at 30 frames a
second; the body's root stays where it is and the camera is fixed (a random orbit
framing the model, as ``mujoco_views.py``), the background rendered once with the
model hidden.  ``jaxpose.Tracker`` with the default ``TrackConfig`` fits frame after
frame.  Scores per frame: symmetric PCP and frames@5cm (``mujoco_views.frames_score``).

Writes experiments/results/tracking/mujoco_track.{json,md}.  Needs the ``mujoco`` extra
and an OpenGL context; without one it says so and exits with status 0.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import mujoco_views as MV  # sets MUJOCO_GL before MuJoCo is imported
import numpy as np

import jaxpose as jp
from jaxpose.camera import depth_to_cloud
from jaxpose.io.atomic import write_json
from jaxpose.metrics import evaluate
from jaxpose.sequences import FREQUENCIES

OUT = os.path.join(MV.ROOT, "experiments", "results", "tracking")
MODELS = [os.path.join(MV.FIXTURES, f) for f in ("ant.xml", "humanoid_lite.xml", "quadruped.urdf")]
FPS = 30.0


def moving_joints(m, root_joints: bool) -> list[tuple[int, float, float]]:
    """``(qpos address, low, high)`` of the hinges and slides that move: all but the root body's
    (``root_joints``), as in ``mujoco_views.random_qpos``; spans from ``mujoco_views.joint_span``."""
    import mujoco

    moving = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    return [(int(m.jnt_qposadr[j]), *MV.joint_span(m, j)) for j in range(m.njnt)
            if int(m.jnt_type[j]) in moving and not (root_joints and MV.is_root_joint(m, j))]


def qpos_motion(m, base, joints, rng, frames: int, amplitude: float) -> np.ndarray:
    """``(frames, nq)``: ``base`` with every moving joint on two sines, clipped to its range."""
    n = len(joints)
    addr = np.array([a for a, _, _ in joints], int)
    lo, hi = (np.array([j[k] for j in joints]) for k in (1, 2))
    amp = amplitude * (hi - lo) / 2 * rng.uniform(0.3, 1.0, (2, n))
    freq = rng.uniform(*FREQUENCIES, (2, n))
    phase = rng.uniform(0, 2 * np.pi, (2, n))
    q = np.repeat(base[None], frames, 0)
    t = np.arange(frames)[:, None, None] / FPS
    q[:, addr] = np.clip(base[addr] + np.sum(amp * np.sin(2 * np.pi * freq * t + phase), 1), lo, hi)
    return q


def run_model(path: str, frames: int, seed: int, spread: float, amplitude: float, size=(640, 480)) -> dict:
    import mujoco

    from jaxpose.kinematics import forward_kinematics

    m, skel, to_pose = MV.load(path)
    d = mujoco.MjData(m)
    renderer = mujoco.Renderer(m, size[1], size[0])
    renderer.enable_depth_rendering()
    urdf = path.lower().endswith(".urdf")
    rng = np.random.default_rng([seed, 7])
    base = MV.random_qpos(m, rng, spread, root_joints=not urdf)
    motion = qpos_motion(m, base, moving_joints(m, not urdf), rng, frames, amplitude)
    d.qpos[:] = base
    mujoco.mj_kinematics(m, d)
    cam, k = MV.camera_view(m, d, rng, *size)
    bg, _, _ = MV.render_depth(renderer, m, d, cam, hide_model=True)
    background = MV.sensor(bg, rng).astype(np.float32) / 1000
    tracker = jp.Tracker(skel, jp.TrackConfig(), seed=seed)
    rows = []
    for i, q in enumerate(motion):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        depth, centre, R = MV.render_depth(renderer, m, d, cam)
        depth = MV.sensor(depth, rng).astype(np.float32) / 1000
        try:
            cloud = depth_to_cloud(depth, k, background=background, max_points=1024, min_points=0)
        except jp.DepthError:  # nothing of the model: the tracker reports the frame lost
            cloud = jp.Cloud(np.zeros((1024, 3), np.float32), np.zeros(1024, np.float32))
        r = tracker.update(cloud)
        links = forward_kinematics(skel, to_pose(q))
        ts, te = ((np.asarray(x, np.float64) - centre) @ R.T for x in (links.start, links.end))
        true_o = (np.asarray(links.origin, np.float64) - centre) @ R.T
        true_R = R @ np.asarray(links.R_world_link, np.float64)
        lost = tracker.mode == "lost"
        ev = None if lost else evaluate(np.asarray(r.links.start), np.asarray(r.links.end), ts, te, skel)
        rows.append({"frame": i, "mode": tracker.mode, "seconds": float(r.wall_time),
                     "pcp": None if lost else ev["symmetric"]["pcp"],
                     "frames_5cm": 0.0 if lost else MV.frames_score(skel, r.links, true_R, true_o),
                     "cost": None if lost else float(r.cost)})
    renderer.close()
    tracked = [f["seconds"] for f in rows if f["mode"] == "tracked"]
    pcps = [f["pcp"] or 0.0 for f in rows]  # the model never leaves the view: a lost frame placed nothing
    return {"model": os.path.splitext(os.path.basename(path))[0], "links": skel.num_links, "frames": len(rows),
            "pcp": float(np.mean(pcps)), "pcp_min": float(np.min(pcps)),
            "frames_5cm": float(np.mean([f["frames_5cm"] for f in rows])),
            "fps": len(tracked) / sum(tracked) if tracked else None,
            "median_frame_ms": 1000 * float(np.median(tracked)) if tracked else None,
            "first_frame_s": rows[0]["seconds"], "global_frames": sum(f["mode"] == "global" for f in rows),
            "lost_frames": sum(f["mode"] == "lost" for f in rows), "per_frame": rows}


def markdown(rows, machine: str) -> str:
    lines = ["| model | links | frames | PCP per frame (lowest) | frames@5cm | frames/s (median ms) | first frame s "
             "| global frames |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        pcp = f"{100 * r['pcp']:.1f}% ({100 * r['pcp_min']:.0f}%)"
        fps = "-" if r["fps"] is None else f"{r['fps']:.0f} ({r['median_frame_ms']:.0f})"
        lines.append(f"| {r['model']} | {r['links']} | {r['frames']} | {pcp} | {100 * r['frames_5cm']:.1f}% | {fps} "
                     f"| {r['first_frame_s']:.0f} | {r['global_frames']} |")
    return "\n".join(lines) + f"\n\nMachine: {machine}. Rendered by MuJoCo; symmetric PCP, frames@5cm strict.\n"


def _amplitude(text: str) -> float:
    v = float(text)
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"must lie in [0, 1], got {text}")
    return v


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", default=MODELS, help="MJCF or URDF files, or gymnasium:NAME.xml")
    ap.add_argument("--frames", type=MV.at_least_one, default=60)
    ap.add_argument("--seed", type=int, default=2, help="the motions' and cameras' draw (default 2)")
    ap.add_argument("--spread", type=MV.spread_arg, default=0.3, help="the base pose's spread (as mujoco_views)")
    ap.add_argument("--amplitude", type=_amplitude, default=0.2, help="the sines' amplitude, of half each range")
    ap.add_argument("--out", default=OUT)
    args = ap.parse_args(argv)
    problem = MV.gl_problem()
    if problem:
        print(f"mujoco_track: skipped: {problem}")
        return 0
    from machine import machine_id, machine_info
    from outputs import write_text

    os.makedirs(args.out, exist_ok=True)
    rows = []
    for path in args.models:
        t0 = time.time()
        try:
            row = run_model(os.path.abspath(MV.public_model(path)), args.frames, args.seed, args.spread,
                            args.amplitude)
        except (jp.JaxposeError, ValueError) as e:  # e.g. a mesh MuJoCo cannot find: the others still run
            print(f"{os.path.basename(path)}: skipped: {' '.join(str(e).split())[:200]}", flush=True)
            continue
        rows.append(row)
        print(f"{row['model']}: PCP {100 * row['pcp']:.1f}%, frames@5cm {100 * row['frames_5cm']:.1f}%, "
              f"{row['fps'] or 0:.0f} frames/s, {time.time() - t0:.0f} s in all", flush=True)
    machine = machine_id()
    write_json(os.path.join(args.out, "mujoco_track.json"),
               {"machine": machine_info(), "seed": args.seed, "amplitude": args.amplitude,
                "spread": "uniform" if args.spread is None else args.spread,
                "config": jp.TrackConfig().to_dict(), "rows": rows})
    table = markdown(rows, machine)
    write_text(os.path.join(args.out, "mujoco_track.md"), table)
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
