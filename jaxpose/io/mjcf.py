"""MuJoCo MJCF files -> :class:`~jaxpose.skeleton.Skeleton`, and MuJoCo joint values -> :class:`Pose`.

The file is compiled by the official ``mujoco`` package (the optional extra
``jaxpose[mujoco]``), so defaults, classes, ``childclass``, includes, ``fromto``,
``euler``/``axisangle``/``zaxis`` orientations and ``<compiler angle=...>`` are
resolved by MuJoCo itself; the importer reads the compiled body tree
(``body_parentid``, ``body_pos``, ``body_quat``, ``jnt_*``, ``geom_*``).

Mapping.  Every body except the world body becomes a jaxpose link of the same
name (an unnamed body: ``body<id>``) whose frame is the MuJoCo body frame, so
``forward_kinematics(...).origin`` equals MuJoCo's ``data.xpos``:

==========================  ================================================================
MJCF                        jaxpose
==========================  ================================================================
``<body pos quat>``         ``offset = pos``, ``rest_matrix = R(quat)``, ``attach = 0``
no joint                    ``fixed`` (the body is welded to its parent)
``hinge``                   ``hinge`` about the joint axis; angle ``qpos - qpos0`` (``ref``);
                            limits ``range - ref``, unlimited: [-180, 180] degrees
``ball``                    ``ball`` (roll, pitch, yaw of the joint quaternion);
                            a limited ball of range ``r``: [-r, r] for each angle
``slide``                   ``slide`` along the joint axis; displacement ``qpos - qpos0``;
                            limits ``range - ref`` (metres), unlimited: +- the model's
                            size (its body geoms' bounding radius at ``qpos0``)
``free``                    the searched root pose (top-level body only, at most one)
joints of the only          the searched root pose: the camera does not know the world, so
top-level body              a planar root (``rootx``/``rootz`` slides and a hinge, as in
                            half_cheetah or walker2d) adds nothing to the root's six DOF
several joints on a body    a chain of zero-length, zero-radius links ``body/joint`` with one
                            joint each; the body's own link comes last and carries the geometry
==========================  ================================================================

A hinge or ball rotates about its anchor (``<joint pos>``); a slide moves the whole
body frame, so its anchor is taken to be the previous joint's (or the body origin).
The link carrying a joint has its origin at the anchor; when the last joint of a body is anchored away from the body
origin, the body link itself is a ``fixed`` link back at the body origin.
Top-level bodies hang from the searched root frame (the world of the file), except
when the world holds one body and that body has joints (a free joint, or
slides, hinges, a ball): then the body's frame is the searched root frame and its
joints are not searched separately, as they would only repeat the root's degrees
of freedom (the body's ``pos``/``quat`` go into the root pose too).  A free body may
not share the world with other top-level bodies.  With ``search_lengths`` the
ranges are as in :mod:`jaxpose.io.capsules`.  Equality
constraints, tendons, sites, actuators and the world body's own geoms (floors)
are ignored.

Geometry.  Every geom of a body except planes, height fields and SDFs is turned
into balls enclosing it (:mod:`jaxpose.io.capsules` explains the construction), and
the body's link gets the one capsule that encloses all of them:

* ``capsule``: exact (MuJoCo's capsule runs along the geom's z axis, ``size[0]`` the
  radius, ``size[1]`` the half-length); ``sphere``: a zero-length capsule;
* ``cylinder``: the capsule of the same axis, radius and segment (encloses it);
* ``ellipsoid``: along its longest axis with the larger other radius (encloses it);
* ``box``: enclosing its eight corners, normally along its longest side with the
  half-diagonal of the two others as radius;
* ``mesh``: enclosing every vertex of the compiled mesh (MuJoCo reads the file); a body
  of meshes only (16 vertices or more) gets the capsule fitted to their vertices instead
  (:func:`~jaxpose.io.capsules.link_capsule`).

That is the one-capsule model (``max_capsules=1``); by default a body gets up to
:data:`~jaxpose.io.capsules.MAX_CAPSULES` capsules, one per geom and flat boxes and disks
cut into slabs (:func:`~jaxpose.io.capsules.link_capsules`), the extra ones as fixed child
links ``<body>#capsule2``, ...
"""

from __future__ import annotations

import os

import jax.numpy as jnp
import numpy as np

from ..errors import SkeletonError
from ..geometry import matrix_to_rpy, quat_to_matrix
from ..skeleton import LinkSpec, Pose, Skeleton, build_skeleton
from .capsules import (
    MAX_CAPSULES, ROBOT_SCALE_RANGE, box_shape, capsule_shape, capsule_specs, check_max_capsules, cylinder_shape,
    ellipsoid_shape, points_shape, sphere_shape,
)

_MISSING = "MJCF support needs the 'mujoco' extra: pip install 'jaxpose[mujoco]'"
_FREE, _BALL, _SLIDE, _HINGE = 0, 1, 2, 3  # mjtJoint
_PLANE, _HFIELD, _SPHERE, _CAPSULE, _ELLIPSOID, _CYLINDER, _BOX, _MESH = range(8)  # mjtGeom


def _import_mujoco():
    try:
        import mujoco
    except ImportError:
        raise SkeletonError(_MISSING) from None
    return mujoco


def compile_mjcf(path):
    """Compile an MJCF file with MuJoCo; any failure becomes one :class:`SkeletonError`."""
    path = str(path)
    if not os.path.exists(path):
        raise SkeletonError(f"{path}: skeleton file not found")
    if os.path.isdir(path):
        raise SkeletonError(f"{path}: is a directory, not a skeleton file")
    mujoco = _import_mujoco()
    try:
        return mujoco.MjModel.from_xml_path(path)
    except Exception as e:  # MuJoCo raises ValueError for XML and compile errors
        msg = "; ".join(line.strip() for line in str(e).splitlines() if line.strip())
        raise SkeletonError(f"{path}: MuJoCo cannot compile the model: {msg}") from None


def load_mjcf(path, *, search_lengths: bool = False, scale_range=ROBOT_SCALE_RANGE,
              max_capsules: int = MAX_CAPSULES) -> Skeleton:
    """Read an MJCF file as a :class:`~jaxpose.skeleton.Skeleton` (see the module docstring).

    Args:
      path: the MJCF ``.xml`` file.
      search_lengths: also search every capsule length within +-30 % (default: fixed).
      scale_range: search range of the global scale (default: held at 1, the robot's size;
        :data:`~jaxpose.io.capsules.SEARCHED_SCALE_RANGE` to search it).
      max_capsules: capsules per body at most (:func:`~jaxpose.io.capsules.link_capsules`); the extra
        ones are fixed child links named ``body#capsule2``, ...; 1: one capsule per body.

    Raises:
      SkeletonError: one message naming the file and the problem (also when the
        ``mujoco`` package is missing or MuJoCo cannot compile the file).
    """
    path = str(path)
    check_max_capsules(max_capsules, path)
    model = compile_mjcf(path)
    return skeleton_from_model(model, source=path, search_lengths=search_lengths, scale_range=scale_range,
                               max_capsules=max_capsules)


def skeleton_from_model(model, *, source: str = "<mjcf>", search_lengths: bool = False,
                        scale_range=ROBOT_SCALE_RANGE, name: str | None = None,
                        max_capsules: int = MAX_CAPSULES) -> Skeleton:
    """Build the skeleton of a compiled ``mujoco.MjModel`` (``source`` names it in errors)."""
    specs, _, _ = _plan(model, source, search_lengths, max_capsules=check_max_capsules(max_capsules, source))
    if name is None:
        name = bytes(model.names).split(b"\0", 1)[0].decode() or os.path.splitext(os.path.basename(source))[0]
    return build_skeleton(name, specs, scale_range=scale_range, source=source, require_geometry=False)


def pose_from_qpos(skel: Skeleton, model, qpos) -> Pose:
    """The jaxpose :class:`Pose` (scale 1) of MuJoCo joint values ``qpos`` (``(model.nq,)``).

    The root pose is the world pose of the body whose joints became the root (a
    free joint's position and orientation; see the module docstring), by MuJoCo's
    own ``mj_kinematics``; hinge angles and slide displacements are measured from
    ``qpos0``; ball quaternions become roll, pitch, yaw.  ``skel`` must come from the
    same model (:func:`skeleton_from_model` or :func:`load_mjcf`).
    """
    qpos = np.asarray(qpos, float).reshape(-1)
    if qpos.shape != (model.nq,):
        raise ValueError(f"qpos must have shape ({model.nq},), got {qpos.shape}")
    _, joint_links, root_body = _plan(model, "<mjcf>", False, geometry=False)
    root_t, root_rpy = np.zeros(3), np.zeros(3)
    if root_body is not None:
        mujoco = _import_mujoco()
        data = mujoco.MjData(model)
        data.qpos[:] = qpos
        mujoco.mj_kinematics(model, data)
        root_t = np.array(data.xpos[root_body], float)
        root_rpy = matrix_to_rpy(np.asarray(data.xmat[root_body], float).reshape(3, 3))
    angles = np.zeros((skel.num_links, 3))
    for link, j in joint_links:
        adr, jt = int(model.jnt_qposadr[j]), int(model.jnt_type[j])
        if jt in (_HINGE, _SLIDE):
            angles[skel.index(link), 0] = qpos[adr] - model.qpos0[adr]
        elif jt == _BALL:
            angles[skel.index(link)] = matrix_to_rpy(quat_to_matrix(qpos[adr : adr + 4]))
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    return Pose(f32(root_t), f32(root_rpy), f32(1.0), f32(angles), f32(skel.length))


# --------------------------------------------------------------------------- the compiled tree


def _names(model, count, kind, default):
    return [getattr(model, kind)(i).name or f"{default}{i}" for i in range(count)]


def _plan(model, source, search_lengths, geometry=True, max_capsules=MAX_CAPSULES):
    """LinkSpecs of the compiled model, ``[(link name, joint id)]`` for every searched joint, and the
    body whose joints are the root pose (``None``: the root frame is the world's)."""

    def fail(msg):
        raise SkeletonError(f"{source}: {msg}")

    nb = int(model.nbody)
    if nb <= 1:
        fail("the model has no bodies (only the world body)")
    body_names = _names(model, nb, "body", "body")
    joint_names = _names(model, int(model.njnt), "joint", "joint")
    parent = np.asarray(model.body_parentid)
    jnt_body = np.asarray(model.jnt_bodyid)
    jtype = np.asarray(model.jnt_type)

    free_bodies = []
    for j in range(model.njnt):
        b = int(jnt_body[j])
        if jtype[j] == _FREE:
            if parent[b] != 0:
                fail(f"joint {joint_names[j]!r}: a free joint is only supported on a top-level body, "
                     f"not on {body_names[b]!r}")
            if np.count_nonzero(jnt_body == b) > 1:
                fail(f"body {body_names[b]!r}: a free joint must be the body's only joint")
            free_bodies.append(b)
    top = [b for b in range(1, nb) if parent[b] == 0]
    if len(free_bodies) > 1:
        fail(f"{len(free_bodies)} bodies have free joints ({', '.join(repr(body_names[b]) for b in free_bodies)}); "
             "jaxpose fits one articulated skeleton with one root pose")
    if free_bodies and len(top) > 1:
        other = next(b for b in top if b != free_bodies[0])
        fail(f"body {body_names[free_bodies[0]]!r} floats freely while body {body_names[other]!r} is attached "
             "to the world; jaxpose moves the whole skeleton with one root pose")

    # the only top-level body's joints (a free joint, or a planar root of slides and a hinge) only repeat
    # the searched root pose's degrees of freedom: that body's frame is the root frame
    root_body = top[0] if len(top) == 1 and np.any(jnt_body == top[0]) else None
    shapes = _geometry(model) if geometry else [[] for _ in range(nb)]
    unlimited_slide = np.any((jtype == _SLIDE) & ~np.asarray(model.jnt_limited, bool))
    reach = _reach(model) if unlimited_slide else None
    taken = set(body_names[1:])
    specs, joint_links = [], []
    for b in range(1, nb):
        bname = body_names[b]
        parent_link = body_names[parent[b]] if parent[b] != 0 else None
        pos = np.asarray(model.body_pos[b], float)
        R = quat_to_matrix(model.body_quat[b])
        joints = [j for j in range(model.njnt) if jnt_body[j] == b]
        if b == root_body:
            pos, R, joints = np.zeros(3), np.eye(3), []  # the body pose is the root pose
        prev = None  # anchor of the previous joint of this body (in the body frame)
        on_body = False
        for m, j in enumerate(joints):
            anchor = np.asarray(model.jnt_pos[j], float)
            if jtype[j] == _SLIDE:  # a slide moves the whole frame: its anchor is any point, take the last one
                anchor = prev if prev is not None else np.zeros(3)
            on_body = m == len(joints) - 1 and np.all(np.abs(anchor) < 1e-12)
            if on_body:
                lname = bname
            else:
                lname = f"{bname}/{joint_names[j]}"
                if lname in taken:
                    lname = f"{lname}#{j}"
                taken.add(lname)
            if prev is None:
                where = dict(offset=tuple(pos + R @ anchor), rest_matrix=R)
            else:
                where = dict(offset=tuple(anchor - prev), rest_matrix=np.eye(3))
            kind = _joint_spec(model, j, reach)
            geom, extras = (capsule_specs(lname, shapes[b], search_lengths, max_capsules) if on_body
                            else (dict(length=0.0, radius=0.0), []))
            specs.append(LinkSpec(name=lname, parent=parent_link, attach=0.0, **where, **kind, **geom))
            specs += _unique(extras, taken, fail)
            joint_links.append((lname, j))
            parent_link, prev = lname, anchor
        if not on_body:
            if prev is None:
                where = dict(offset=tuple(pos), rest_matrix=R)
            else:
                where = dict(offset=tuple(-prev), rest_matrix=np.eye(3))
            geom, extras = capsule_specs(bname, shapes[b], search_lengths, max_capsules)
            specs.append(LinkSpec(name=bname, parent=parent_link, attach=0.0, joint="fixed", **where, **geom))
            specs += _unique(extras, taken, fail)
    return specs, joint_links, root_body


def _unique(extras, taken: set, fail):
    """The extra capsules' links, their names checked against (and added to) the names ``taken``."""
    for e in extras:
        if e.name in taken:
            fail(f"body {e.parent!r}: the name {e.name!r} of its extra capsule is taken by another link")
        taken.add(e.name)
    return extras


def _reach(model) -> float:
    """The model's size at ``qpos0``: the largest distance of a body geom's bounding sphere from the
    geoms' mean centre (world-body geoms such as floors left out; bodies only when there are no geoms)."""
    mujoco = _import_mujoco()
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    on_body = np.asarray(model.geom_bodyid) > 0
    if on_body.any():
        pts, r = np.asarray(data.geom_xpos)[on_body], np.asarray(model.geom_rbound)[on_body]
    else:
        pts, r = np.asarray(data.xpos)[1:], 0.0
    return max(float(np.max(np.linalg.norm(pts - pts.mean(0), axis=1) + r)), 0.1)


def _joint_spec(model, j, reach=None):
    jt = int(model.jnt_type[j])
    limited = bool(model.jnt_limited[j])
    lo, hi = (float(v) for v in model.jnt_range[j])
    if jt in (_HINGE, _SLIDE):
        ref = float(model.qpos0[model.jnt_qposadr[j]])
        axis = tuple(np.asarray(model.jnt_axis[j], float))
        if jt == _SLIDE:  # metres; an unlimited slide moves within the model's size (:func:`_reach`)
            lim = [lo - ref, hi - ref] if limited else [-reach, reach]
            return dict(joint="slide", axis=axis, limits=[list(map(float, lim))])
        lim = np.rad2deg([lo - ref, hi - ref]) if limited else [-180.0, 180.0]
        return dict(joint="hinge", axis=axis, limits=[list(map(float, lim))])
    r = min(float(np.rad2deg(hi)), 180.0) if limited else 180.0
    return dict(joint="ball", limits=[[-r, r]] * 3)


def _geometry(model):
    """For every body, the list of :class:`~jaxpose.io.capsules.Shape` of its geoms (body frame)."""
    shapes = [[] for _ in range(model.nbody)]
    for g in range(model.ngeom):
        b = int(model.geom_bodyid[g])
        if b == 0:
            continue
        t = int(model.geom_type[g])
        pos = np.asarray(model.geom_pos[g], float)
        R = quat_to_matrix(model.geom_quat[g])
        size = np.asarray(model.geom_size[g], float)
        if t == _SPHERE:
            shapes[b].append(sphere_shape(pos, size[0]))
        elif t in (_CAPSULE, _CYLINDER):
            shapes[b].append((cylinder_shape if t == _CYLINDER else capsule_shape)(pos, R, size[0], size[1]))
        elif t == _ELLIPSOID:
            shapes[b].append(ellipsoid_shape(pos, R, size))
        elif t == _BOX:
            shapes[b].append(box_shape(pos, R, size))
        elif t == _MESH and model.geom_dataid[g] >= 0:
            m = int(model.geom_dataid[g])
            adr, n = int(model.mesh_vertadr[m]), int(model.mesh_vertnum[m])
            verts = np.asarray(model.mesh_vert[adr : adr + n], float)
            shapes[b].append(points_shape(pos + verts @ R.T))
    return shapes
