"""URDF robot files -> :class:`~jaxpose.skeleton.Skeleton`.

Mapping.  Every URDF ``<link>`` becomes a jaxpose link of the same name; every
``<joint>`` sets the frame of its child link in its parent link's frame:

==============================  ==========================================================
URDF                            jaxpose
==============================  ==========================================================
``<link name>``                 link ``name`` (the root link hangs from the searched root)
joint ``<origin xyz rpy>``      ``offset = xyz``, ``rest_matrix = Rz(y) Ry(p) Rx(r)``, ``attach = 0``
``revolute``                    ``hinge`` about ``<axis xyz>`` (joint frame), ``<limit lower upper>``
``continuous``                  ``hinge``, limits [-180, 180] degrees
``prismatic``                   ``slide`` along ``<axis xyz>``, ``<limit lower upper>`` (metres)
``spherical`` (PyBullet)        ``ball``, limits [-180, 180] degrees on each angle
``fixed``                       ``fixed`` (a zero-DOF link)
``floating``, ``planar``        rejected (the root pose is always searched anyway)
``<mimic>``                     ignored: the joint is searched independently
==============================  ==========================================================

The frames are those of the URDF: with ``attach = 0`` a link's anchor is just its
joint origin, so ``forward_kinematics(...).origin`` is the URDF link origin.

Geometry.  ``<collision>`` elements are used when a link has any, otherwise its
``<visual>`` elements.  Each becomes a shape of :mod:`jaxpose.io.capsules` (``sphere``,
``cylinder``, ``capsule`` (a common extension), ``box``), which gives the link its capsules.
A ``mesh`` in a Wavefront ``.obj`` or an STL file found beside the URDF
(:func:`~jaxpose.io.mesh.find_mesh_file`) is read: its vertices, scaled by ``scale`` and
placed by the geometry's origin, become a point set.  A mesh that cannot be found or is of
another format (e.g. COLLADA ``.dae``) is stood in for by a ball of radius
:data:`DEFAULT_MESH_RADIUS` times the largest ``scale`` factor at the geometry's origin; give
the link a ``<collision>`` primitive for a better fit.  A mesh file that is found but
unreadable is an error.

Why the standard library parser.  URDF is plain XML and the importer needs only
its stable core (``link``, ``joint``, ``origin``, ``axis``, ``limit``,
``collision``/``visual`` geometry); ``xml.etree.ElementTree`` reads that subset in
a few lines, so no extra dependency (``urdfdom``, ``yourdfpy``, ...) is needed and
error messages stay ours.  ROS ``package://`` paths and xacro macros are not
resolved: expand xacro files to plain URDF first.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET

import numpy as np

from ..errors import SkeletonError
from ..geometry import rpy_matrix
from ..skeleton import LinkSpec, Skeleton, build_skeleton
from .capsules import (
    MAX_CAPSULES, ROBOT_SCALE_RANGE, Shape, box_shape, capsule_shape, capsule_specs, check_max_capsules, cylinder_shape,
    points_shape, sphere_shape,
)
from .mesh import find_mesh_file, read_mesh_vertices

DEFAULT_MESH_RADIUS = 0.05  # metres: stand-in ball for a mesh that is not read


def load_urdf(path, *, search_lengths: bool = False, scale_range=ROBOT_SCALE_RANGE,
              max_capsules: int = MAX_CAPSULES) -> Skeleton:
    """Read a URDF file as a :class:`~jaxpose.skeleton.Skeleton` (see the module docstring).

    Args:
      path: the ``.urdf`` file.
      search_lengths: also search every capsule length within +-30 % (default: fixed).
      scale_range: search range of the global scale (default: held at 1, the robot's size;
        :data:`~jaxpose.io.capsules.SEARCHED_SCALE_RANGE` to search it).
      max_capsules: capsules per link at most (:func:`~jaxpose.io.capsules.link_capsules`); the extra ones are fixed
        child links named ``link#capsule2``, ...; 1: one capsule per link.

    Returns:
      The skeleton; link names are the URDF link names (and those of extra capsules).

    Raises:
      SkeletonError: one message naming the file and the problem.
    """
    path = str(path)
    max_capsules = check_max_capsules(max_capsules, path)
    root = _read_xml(path)
    specs, name = _urdf_specs(root, path, search_lengths, max_capsules)
    return build_skeleton(name, specs, scale_range=scale_range, source=path, require_geometry=False)


def _read_xml(path: str) -> ET.Element:
    if not os.path.exists(path):
        raise SkeletonError(f"{path}: skeleton file not found")
    if os.path.isdir(path):
        raise SkeletonError(f"{path}: is a directory, not a skeleton file")
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as e:
        raise SkeletonError(f"{path}: malformed XML: {e}") from None
    except OSError as e:
        raise SkeletonError(f"{path}: cannot read the file ({e.__class__.__name__}: {e})") from None


def _numbers(text, n, what, default, fail):
    if text is None:
        return np.asarray(default, float)
    try:
        a = np.array([float(x) for x in text.split()], float)
    except ValueError:
        a = None
    if a is None or a.shape != (n,) or not np.all(np.isfinite(a)):
        fail(f"{what} must be {n} number{'s' if n > 1 else ''}, got {text!r}")
    return a


def _origin(elem, what, fail):
    o = elem.find("origin") if elem is not None else None
    if o is None:
        return np.zeros(3), np.eye(3)
    xyz = _numbers(o.get("xyz"), 3, f"{what} <origin xyz>".strip(), (0, 0, 0), fail)
    rpy = _numbers(o.get("rpy"), 3, f"{what} <origin rpy>".strip(), (0, 0, 0), fail)
    return xyz, rpy_matrix(rpy)


def _urdf_geometry(link, where, fail, base: str = ".") -> list[Shape]:
    elems = link.findall("collision") or link.findall("visual")
    shapes = []
    for k, el in enumerate(elems):
        what = f"{where} <{el.tag}> #{k + 1}"
        geo = el.find("geometry")
        if geo is None or len(geo) == 0:
            fail(f"{what} has no <geometry>")
        g = geo[0]
        pos, R = _origin(el, what, fail)

        def need(key, n=1):
            if g.get(key) is None:
                fail(f"{what} <{g.tag}> needs a {key!r} attribute")
            v = _numbers(g.get(key), n, f"{what} <{g.tag} {key}>", None, fail)
            return float(v[0]) if n == 1 else v

        if g.tag == "sphere":
            shapes.append(sphere_shape(pos, abs(need("radius"))))
        elif g.tag in ("cylinder", "capsule"):
            make = cylinder_shape if g.tag == "cylinder" else capsule_shape
            shapes.append(make(pos, R, abs(need("radius")), 0.5 * abs(need("length"))))
        elif g.tag == "box":
            shapes.append(box_shape(pos, R, 0.5 * need("size", 3)))
        elif g.tag == "mesh":
            s = _numbers(g.get("scale"), 3, f"{what} <mesh scale>", (1, 1, 1), fail)
            mesh = find_mesh_file(g.get("filename") or "", base)
            if mesh is None:
                shapes.append(sphere_shape(pos, DEFAULT_MESH_RADIUS * float(np.max(np.abs(s)))))
            else:
                try:
                    v = read_mesh_vertices(mesh)
                except ValueError as e:
                    fail(f"{what} <mesh filename={g.get('filename')!r}>: {mesh}: {e}")
                shapes.append(points_shape(pos + (v * np.asarray(s, float)) @ np.asarray(R, float).T))
        else:
            fail(f"{what}: unsupported geometry <{g.tag}> (expected box, cylinder, sphere, capsule or mesh)")
    return shapes


def _urdf_specs(root, path, search_lengths, max_capsules=MAX_CAPSULES):
    def fail(msg):
        raise SkeletonError(f"{path}: {msg}")

    if root.tag != "robot":
        fail(f"not a URDF file: the root element is <{root.tag}>, expected <robot>")
    links = {}
    for el in root.findall("link"):
        name = el.get("name")
        if not name:
            fail("every <link> needs a non-empty 'name'")
        if name in links:
            fail(f"duplicate link name {name!r}")
        links[name] = el
    if not links:
        fail("the robot has no links")

    joint_of_child = {}  # child link -> (joint name, spec fields)
    for k, el in enumerate(root.findall("joint")):
        jname = el.get("name") or f"#{k + 1}"
        where = f"joint {jname!r}"
        jfail = lambda msg, where=where: fail(f"{where}: {msg}")  # noqa: E731
        jtype = el.get("type")
        ends = {}
        for tag in ("parent", "child"):
            e = el.find(tag)
            if e is None or not e.get("link"):
                jfail(f"needs a <{tag} link=...> element")
            if e.get("link") not in links:
                jfail(f"refers to a missing {tag} link {e.get('link')!r}")
            ends[tag] = e.get("link")
        if jtype in ("floating", "planar"):
            jfail(f"{jtype} joints are not supported (the root pose is searched anyway; remove the joint "
                  "and let the child link be the root)")
        if jtype not in ("revolute", "continuous", "prismatic", "fixed", "spherical"):
            jfail(f"unknown joint type {jtype!r} (expected revolute, continuous, prismatic, fixed or spherical)")
        child = ends["child"]
        if child in joint_of_child:
            fail(f"closed loop: link {child!r} is the child of both joint {joint_of_child[child][0]!r} "
                 f"and joint {jname!r}")
        if child == ends["parent"]:
            jfail(f"closed loop: link {child!r} is its own parent")
        xyz, R = _origin(el, "", jfail)
        spec = dict(parent=ends["parent"], offset=tuple(xyz), rest_matrix=R, attach=0.0)
        if jtype == "fixed":
            spec["joint"] = "fixed"
        elif jtype == "spherical":
            spec.update(joint="ball", limits=[[-180.0, 180.0]] * 3)
        else:
            axis = _numbers(el.find("axis").get("xyz") if el.find("axis") is not None else None, 3,
                            "<axis xyz>", (1, 0, 0), jfail)
            if not np.linalg.norm(axis) > 0:
                jfail("the joint axis must be a non-zero vector")
            spec.update(joint="slide" if jtype == "prismatic" else "hinge", axis=tuple(axis / np.linalg.norm(axis)))
            if jtype == "continuous":
                spec["limits"] = [[-180.0, 180.0]]
            else:
                lim = el.find("limit")
                if lim is None:
                    jfail(f"a {jtype} joint needs a <limit lower=... upper=...> element")
                lo = _numbers(lim.get("lower"), 1, "<limit lower>", (0.0,), jfail)[0]
                hi = _numbers(lim.get("upper"), 1, "<limit upper>", (0.0,), jfail)[0]
                if lo > hi:
                    jfail(f"inverted limits lower={lo} > upper={hi}")
                # a revolute joint's limits in radians (LinkSpec: degrees); a prismatic joint's in metres
                spec["limits"] = [[lo, hi] if jtype == "prismatic" else [float(np.rad2deg(lo)), float(np.rad2deg(hi))]]
        joint_of_child[child] = (jname, spec)

    roots = [n for n in links if n not in joint_of_child]
    if not roots:
        fail("closed loop: every link is the child of a joint, so there is no root link")
    if len(roots) > 1:
        fail(f"the links do not form one tree: {len(roots)} root links ({', '.join(map(repr, roots[:5]))}"
             f"{', ...' if len(roots) > 5 else ''}); connect them with joints")
    # a cycle not containing the root: walk up from every link
    for name in links:
        seen, n = set(), name
        while n in joint_of_child:
            if n in seen:
                fail(f"closed loop: the joints around link {n!r} form a cycle")
            seen.add(n)
            n = joint_of_child[n][1]["parent"]

    specs, extras = [], []
    for name, el in links.items():
        geom, more = capsule_specs(name, _urdf_geometry(el, f"link {name!r}", fail,
                                                        os.path.dirname(os.path.abspath(path))),
                                   search_lengths, max_capsules)
        if name in joint_of_child:
            specs.append(LinkSpec(name=name, **joint_of_child[name][1], **geom))
        else:
            specs.append(LinkSpec(name=name, parent=None, joint="fixed", attach=0.0, **geom))
        extras += more
    for e in extras:
        if e.name in links:
            fail(f"link {e.parent!r}: the name {e.name!r} of its extra capsule is taken by another link")
    specs += extras
    robot_name = root.get("name") or os.path.splitext(os.path.basename(path))[0]
    return specs, robot_name
