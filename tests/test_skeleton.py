"""Skeleton construction, validation, genome layout, bounds and encode/decode."""

from __future__ import annotations

import copy
import os
import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose.errors import SkeletonError
from jaxpose.io.skeleton_file import load_skeleton, skeleton_from_dict
from jaxpose.genome import decode, encode, genome_bounds, genome_layout
from jaxpose.skeleton import LinkSpec, Pose, build_skeleton, rest_pose

SKELETON_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "skeletons")
SHIPPED = ["spider", "humanoid", "arm7", "snake"]
DOF = {"ball": 3, "hinge": 1, "fixed": 0}


def raw(name):
    with open(os.path.join(SKELETON_DIR, f"{name}.toml"), "rb") as f:
        return tomllib.load(f)


@pytest.fixture(scope="module")
def skeletons():
    return {n: load_skeleton(n) for n in SHIPPED}


# --------------------------------------------------------------------------- degrees of freedom


@pytest.mark.parametrize("name, documented", [("spider", 39), ("humanoid", 75), ("arm7", 21), ("snake", 47)])
def test_dof_counts(skeletons, name, documented):
    skel = skeletons[name]
    links = raw(name)["link"]
    independent = 7 + sum(DOF[l.get("joint", "ball")] for l in links) + sum(
        1 for l in links if "length_range" in l and l["length_range"][0] < l["length_range"][1]
    )
    assert skel.num_dof == independent == documented  # documented in the files' headers
    assert skel.num_links == len(links)
    layout = genome_layout(skel)
    assert layout.size == independent and len(set(layout.names)) == layout.size
    assert len(set(layout.target)) == layout.size  # no two genes drive one parameter
    assert layout.names[:7] == ("root_tx", "root_ty", "root_tz", "root_roll", "root_pitch", "root_yaw", "scale")
    # genes of a link are grouped and follow topological order
    owners = [l for l in layout.link_of_gene if l >= 0]
    assert owners == sorted(owners)
    for i in range(skel.num_links):
        n_genes = int(layout.gene_mask([i]).sum())
        assert n_genes == DOF[skel.joint_types[i]] + int(skel.length_searched[i])


def test_topology_helpers(skeletons):
    skel = skeletons["humanoid"]
    assert all(p < i for i, p in enumerate(skel.parents))
    levels = skel.levels
    assert sorted(i for lev in levels for i in lev) == list(range(skel.num_links))
    for k, lev in enumerate(levels):
        for i in lev:
            assert (skel.parents[i] < 0) == (k == 0)
            if k:
                assert skel.parents[i] in levels[k - 1]
    up = skel.index("upper_spine")
    sub = set(skel.subtree(up))
    for j in range(skel.num_links):  # j is below upper_spine iff walking up reaches it
        p, below = j, False
        while p >= 0:
            below |= p == up
            p = skel.parents[p]
        assert below == (j in sub)
    assert set(skel.children[up]) == {j for j, p in enumerate(skel.parents) if p == up}
    with pytest.raises(KeyError):
        skel.index("tail")


# --------------------------------------------------------------------------- bounds and encode/decode


def physical_limits(name, skel, centre, extent):
    """Independent per-parameter ranges from the raw file: ``{param: (lo, hi)}``."""
    data = raw(name)
    lim = {}
    for k, ax in enumerate("xyz"):
        lim[f"root_t{ax}"] = (centre[k] - extent, centre[k] + extent)
    lim["root_roll"], lim["root_pitch"], lim["root_yaw"] = (-np.pi, np.pi), (-np.pi / 2, np.pi / 2), (-np.pi, np.pi)
    lim["scale"] = tuple(data.get("scale_range", (0.5, 2.0)))
    for l in data["link"]:
        dof = DOF[l.get("joint", "ball")]
        limits = l.get("limits", [[-180, 180]] * dof)
        for a in range(dof):
            lim[f"{l['name']}.q{a}"] = tuple(np.deg2rad(limits[a]))
        lim[f"{l['name']}.length"] = tuple(l.get("length_range", (l["length"], l["length"])))
    return lim


def pose_params(skel, pose):
    """Every parameter of a single pose by name."""
    out = {f"root_t{ax}": float(pose.root_t[k]) for k, ax in enumerate("xyz")}
    out.update(root_roll=float(pose.root_rpy[0]), root_pitch=float(pose.root_rpy[1]), root_yaw=float(pose.root_rpy[2]))
    out["scale"] = float(pose.scale)
    for i, n in enumerate(skel.link_names):
        for a in range(3):
            out[f"{n}.q{a}"] = float(pose.angles[i, a])
        out[f"{n}.length"] = float(pose.lengths[i])
    return out


@pytest.mark.parametrize("name", SHIPPED)
def test_decode_stays_within_the_documented_limits(skeletons, name):
    skel = skeletons[name]
    centre, extent = np.array([0.1, -0.2, 2.0]), 0.7
    bounds = genome_bounds(skel, centre, extent)
    lim = physical_limits(name, skel, centre, extent)
    rng = np.random.default_rng(0)
    dec = jax.jit(jax.vmap(lambda g: decode(skel, bounds, g)))
    G = rng.uniform(0, 1, (64, skel.num_dof))
    G[0], G[1] = 0.0, 1.0
    G[2] = rng.uniform(-3, 4, skel.num_dof)  # outside [0, 1]: clipped
    poses = dec(jnp.asarray(G, jnp.float32))
    layout = genome_layout(skel)
    searched = set(layout.names)
    for k in range(len(G)):
        p = pose_params(skel, jax.tree.map(lambda x: x[k], poses))
        for key, v in p.items():
            if key in lim:
                lo, hi = lim[key]
                assert lo - 1e-5 <= v <= hi + 1e-5, (key, v, lo, hi)
            else:
                assert v == 0.0, key  # unused DOFs stay 0
            if key.endswith(".length") and key not in searched:
                assert v == pytest.approx(lim[key][0], rel=1e-6)  # fixed lengths keep their value
        if k < 2:  # all-0 and all-1 genomes reach the ends of every range
            for key in searched:
                assert p[key] == pytest.approx(lim[key][k], abs=1e-5), key


@pytest.mark.parametrize("name", SHIPPED)
def test_encode_decode_round_trip(skeletons, name):
    skel = skeletons[name]
    bounds = genome_bounds(skel, [0.0, 0.0, 2.0], 1.0)
    rng = np.random.default_rng(1)
    G = jnp.asarray(rng.uniform(0, 1, (16, skel.num_dof)), jnp.float32)
    rt = jax.jit(jax.vmap(lambda g: encode(skel, bounds, decode(skel, bounds, g))))
    np.testing.assert_allclose(np.asarray(rt(G)), np.asarray(G), atol=2e-5)
    # pose -> genome -> pose for a pose inside the bounds
    pose = decode(skel, bounds, G[3])
    again = decode(skel, bounds, encode(skel, bounds, pose))
    for a, b in zip(again, pose):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-5)
    # outside the ranges: encode clips into [0, 1]
    far = pose._replace(scale=jnp.float32(100.0), root_t=jnp.asarray([50.0, -50.0, 2.0], jnp.float32))
    g = np.asarray(encode(skel, bounds, far))
    assert g.min() >= 0.0 and g.max() <= 1.0
    assert g[6] == 1.0 and g[0] == 1.0 and g[1] == 0.0


def test_zero_width_ranges_round_trip():
    """A gene whose range is a single value (fixed scale, a [0, 0] limit) decodes to it."""
    skel = build_skeleton(
        "flat", [LinkSpec("a", limits=[[0, 0], [-10, 10], [5, 5]], length=0.2)], scale_range=(1.3, 1.3)
    )
    bounds = genome_bounds(skel, [0, 0, 0], 1.0)
    g = jnp.full(skel.num_dof, 0.37)
    pose = decode(skel, bounds, g)
    assert float(pose.scale) == pytest.approx(1.3)
    np.testing.assert_allclose(pose.angles[0], np.deg2rad([0.0, -10 + 0.37 * 20, 5.0]), atol=1e-6)
    back = np.asarray(encode(skel, bounds, pose))
    assert np.all(np.isfinite(back))
    np.testing.assert_allclose(np.asarray(decode(skel, bounds, back).angles), np.asarray(pose.angles), atol=1e-6)


def test_rest_pose_is_inside_the_limits(skeletons):
    skel = build_skeleton("off", [LinkSpec("a", limits=[[10, 20], [-5, 5], [-20, -10]])])
    np.testing.assert_allclose(rest_pose(skel).angles[0], np.deg2rad([10, 0, -10]), atol=1e-6)
    for skel in skeletons.values():
        rp = rest_pose(skel)
        assert isinstance(rp, Pose)
        assert np.all(rp.angles >= skel.angle_lo) and np.all(rp.angles <= skel.angle_hi)


# --------------------------------------------------------------------------- validation


BASE = {
    "name": "t",
    "link": [
        {"name": "body", "length": 0.2, "radius": 0.05},
        {"name": "arm", "parent": "body", "joint": "hinge", "axis": [0, 1, 0], "limits": [[-30, 60]], "length": 0.1},
        {"name": "hand", "parent": "arm", "length": 0.05},
    ],
}


def mutate(fn):
    d = copy.deepcopy(BASE)
    fn(d)
    return d


def _set(i, **kw):
    return lambda d: d["link"][i].update(kw)


BAD = [
    ("unknown parent", _set(1, parent="torso"), "arm", "unknown parent 'torso'"),
    ("cycle", _set(0, parent="hand"), ("body", "arm", "hand"), "cycle"),
    ("own parent", _set(2, parent="hand"), "hand", "own parent"),
    ("duplicate", lambda d: d["link"].append({"name": "arm", "length": 0.1}), "arm", "duplicate"),
    ("zero length", _set(1, length=0.0), "arm", "length must be > 0"),
    ("negative length", _set(2, length=-0.1), "hand", "length must be > 0"),
    ("nan length", _set(2, length=float("nan")), "hand", "length"),
    ("negative radius", _set(0, radius=-0.01), "body", "radius must be >= 0"),
    ("inverted limits", _set(1, limits=[[60, -30]]), "arm", "inverted joint limits"),
    ("limit count", _set(0, limits=[[-10, 10]]), "body", "3 [lo, hi] pair"),
    ("unknown joint", _set(1, joint="slider"), "arm", "unknown joint type 'slider'"),
    ("zero hinge axis", _set(1, axis=[0, 0, 0]), "arm", "hinge axis"),
    ("bad offset", _set(2, offset=[0, 1]), "hand", "'offset' must be 3"),
    ("nan attach", _set(2, attach=float("nan")), "hand", "attach"),
    ("text attach", _set(2, attach="end"), "hand", "attach"),
    ("inverted length range", _set(2, length_range=[0.2, 0.1]), "hand", "length_range"),
    ("unknown key", _set(2, colour="red"), "hand", "unknown key"),
]


@pytest.mark.parametrize("what, fn, link, problem", BAD, ids=[b[0] for b in BAD])
def test_invalid_descriptions_are_rejected_naming_link_and_problem(what, fn, link, problem):
    with pytest.raises(SkeletonError) as e:
        skeleton_from_dict(mutate(fn), source="bad.toml")
    msg = str(e.value)
    assert msg.startswith("bad.toml: ")
    assert problem in msg
    links = link if isinstance(link, tuple) else (link,)
    assert any(f"link {l!r}" in msg for l in links), msg


def test_cycle_error_names_a_link_on_the_cycle():
    # 'leaf' hangs below the cycle a -> b -> a; the message must name a or b
    d = {"link": [{"name": "leaf", "parent": "a"}, {"name": "a", "parent": "b"}, {"name": "b", "parent": "a"}]}
    with pytest.raises(SkeletonError, match=r"link '(a|b)': the parent links form a cycle"):
        skeleton_from_dict(d)


@pytest.mark.parametrize("data", [{}, {"link": []}, {"name": "x"}, []])
def test_empty_descriptions_are_rejected(data):
    with pytest.raises(SkeletonError, match="no links|top level"):
        skeleton_from_dict(data)
    with pytest.raises(SkeletonError, match="no links"):
        build_skeleton("x", [])


def test_build_skeleton_rejects_bad_specs_naming_the_link():
    with pytest.raises(SkeletonError, match=r"link 'b': unknown joint type"):
        build_skeleton("x", [LinkSpec("a"), LinkSpec("b", parent="a", joint=["ball"])])
    with pytest.raises(SkeletonError, match="scale range must be positive"):
        build_skeleton("x", [LinkSpec("a")], scale_range=(0.0, 1.0))
    # importers may pass bodies without geometry
    skel = build_skeleton("x", [LinkSpec("a", length=0.0)], require_geometry=False)
    assert float(skel.length[0]) == 0.0


def test_valid_description_and_file_order(tmp_path):
    d = copy.deepcopy(BASE)
    d["link"] = d["link"][::-1]  # children before parents in the file
    skel = skeleton_from_dict(d)
    assert skel.link_names == ("body", "arm", "hand")
    assert skel.parents == (-1, 0, 1)
    assert skel.joint_types == ("ball", "hinge", "ball")
    np.testing.assert_allclose(skel.attach, [0, 1, 1])  # default: parent's far end; roots 0
    np.testing.assert_allclose(skel.angle_lo[1], [np.deg2rad(-30), 0, 0], atol=1e-7)
    np.testing.assert_allclose(skel.angle_hi[1], [np.deg2rad(60), 0, 0], atol=1e-7)
    np.testing.assert_allclose(skel.axis[1], [0, 1, 0])


def test_deep_chain_file_loads(tmp_path):
    n = 220
    lines = ['name = "deep"']
    for i in range(n):
        lines += ["[[link]]", f'name = "s{i}"', "length = 0.02", "radius = 0.005"]
        if i:
            lines.append(f'parent = "s{i - 1}"')
    path = tmp_path / "deep.toml"
    path.write_text("\n".join(lines))
    skel = load_skeleton(str(path))
    assert skel.num_links == n and len(skel.levels) == n
    assert skel.num_dof == 7 + 3 * n
    assert skel.subtree(n - 2) == (n - 2, n - 1)
    # a bad link deep down is reported by name, with the file
    path.write_text("\n".join(lines).replace('name = "s150"\nlength = 0.02', 'name = "s150"\nlength = -1'))
    with pytest.raises(SkeletonError, match=r"deep\.toml: link 's150': length"):
        load_skeleton(str(path))
