"""Metrics against hand-computed cases, skeleton symmetries, and `jaxpose eval`."""

from __future__ import annotations

import argparse
import json
import os

import numpy as np
import pytest

from jaxpose import metrics as M
from jaxpose.errors import JaxposeError
from jaxpose.io.atomic import write_json
from jaxpose.io.skeleton_file import load_skeleton, shipped_skeletons
from jaxpose.kinematics import forward_kinematics
from jaxpose.skeleton import LinkSpec, build_skeleton, rest_pose

# --------------------------------------------------------------------------- hand-computed cases


def test_pcp_mpjpe_pck_by_hand():
    ts = np.array([[0, 0, 0], [1, 0, 0]], float)
    te = np.array([[1, 0, 0], [1, 0.2, 0]], float)  # lengths 1 and 0.2
    ps = ts + np.array([[0.4, 0, 0], [0, 0.05, 0]])
    pe = te + np.array([[0, 0.3, 0], [0, 0.15, 0]])
    # link 0: errors 0.4, 0.3 <= 0.5 -> correct; link 1: 0.05 ok, 0.15 > 0.1 -> wrong
    np.testing.assert_array_equal(M.pcp(ps, pe, ts, te), [True, False])
    np.testing.assert_array_equal(M.pcp_abs(ps, pe, ts, te), [False, False])
    assert M.mpjpe(ps, pe, ts, te) == pytest.approx(1000 * (0.4 + 0.3 + 0.05 + 0.15) / 4)
    assert M.pck(ps, pe, ts, te) == pytest.approx(1 / 4)
    s = M.scores(ps, pe, ts, te)
    assert s == {"pcp": 0.5, "pcp_10cm": 0.0, "mpjpe_mm": pytest.approx(225.0), "pck_10cm": 0.25}


def test_pcp_uses_the_true_length_and_both_ends():
    ts, te = np.zeros((1, 3)), np.array([[0.2, 0, 0]])
    # a long predicted link: both ends off by exactly half the true length -> correct; a bit more -> wrong
    assert M.pcp(ts + [0, 0.1, 0], te + [0, 0.1, 0], ts, te)[0]
    assert not M.pcp(ts, te + [0, 0.1001, 0], ts, te)[0]


def test_pcp_skips_links_of_zero_length():
    """A sphere or a frame without geometry has no length to judge its placement by: PCP leaves it out,
    MPJPE and PCK keep its points."""
    ts = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 0]], float)
    te = np.array([[1, 0, 0], [1, 0, 0], [1, 0.2, 0]], float)  # lengths 1, 0 and 0.2
    ps = ts + np.array([[0.1, 0, 0], [0.003, 0, 0], [0.3, 0, 0]])
    pe = te.copy()
    np.testing.assert_array_equal(M.pcp_scored(ts, te), [True, False, True])
    s = M.scores(ps, pe, ts, te)
    assert s["pcp"] == 0.5  # link 0 right, link 2 wrong (0.3 > 0.1); link 1 (3 mm off) not scored
    assert s["pcp_10cm"] == pytest.approx(2 / 3) and s["pck_10cm"] == pytest.approx(5 / 6)
    assert s["mpjpe_mm"] == pytest.approx(1000 * (0.1 + 0.003 + 0.3) / 6)
    m = M.evaluate(ps, pe, ts, te, names=["a", "b", "c"])
    assert m["pcp_links"] == 2 and [m["per_link"][n]["correct"] for n in "abc"] == [True, None, False]
    none = M.scores(ps[1:2], pe[1:2], ts[1:2], te[1:2])  # nothing to score
    assert none["pcp"] is None and none["pck_10cm"] == 1.0


# --------------------------------------------------------------------------- symmetries


@pytest.mark.parametrize("name,order", [("spider", 24), ("humanoid", 4), ("arm7", 1), ("snake", 1)])
def test_group_order_of_shipped_skeletons(name, order):
    skel = load_skeleton(name)
    assert M.automorphism_group_order(skel) == order
    perms = M.automorphisms(skel)
    assert len(perms) == order and len({tuple(p) for p in perms}) == order
    np.testing.assert_array_equal(perms[0], np.arange(skel.num_links))


@pytest.mark.parametrize("name", shipped_skeletons())
def test_automorphisms_preserve_tree_and_attributes(name):
    skel = load_skeleton(name)
    attrs = M.link_attributes(skel)
    par = skel.parents
    for p in M.automorphisms(skel):
        assert sorted(p) == list(range(skel.num_links))
        for i in range(skel.num_links):
            assert attrs[p[i]] == attrs[i]
            assert (par[i] < 0 and par[p[i]] < 0) or (par[i] >= 0 and p[par[i]] == par[p[i]])


def test_orbits():
    spider = load_skeleton("spider")
    orbits = {tuple(spider.link_names[i] for i in o) for o in M.link_orbits(spider)}
    assert ("leg0_upper", "leg1_upper", "leg2_upper", "leg3_upper") in orbits
    hum = load_skeleton("humanoid")
    names = [{hum.link_names[i] for i in o} for o in M.link_orbits(hum)]
    assert {"l_hand", "r_hand"} in names and {"head"} in names and {"lower_spine"} in names


def test_attributes_break_symmetry():
    links = [LinkSpec("a", length=0.2, radius=0.02), LinkSpec("b", length=0.2, radius=0.02),
             LinkSpec("c", length=0.2, radius=0.03)]
    skel = build_skeleton("t", links)
    assert M.automorphism_group_order(skel) == 2  # c has another radius
    nested = [LinkSpec("r"), LinkSpec("x", parent="r"), LinkSpec("y", parent="r"),
              LinkSpec("x1", parent="x"), LinkSpec("y1", parent="y", joint="hinge", limits=[[-10, 10]])]
    assert M.automorphism_group_order(build_skeleton("n", nested)) == 1  # the subtrees below differ


def test_best_matching_equals_brute_force():
    skel = load_skeleton("spider")
    perms = M.automorphisms(skel)
    rng = np.random.default_rng(0)
    for _ in range(20):
        C = rng.uniform(size=(skel.num_links, skel.num_links))
        best = M.best_matching(skel, C)
        brute = min(C[np.arange(skel.num_links), p].sum() for p in perms)
        assert C[np.arange(skel.num_links), best].sum() == pytest.approx(brute)
        assert any(np.array_equal(best, p) for p in perms)


def _links(skel, pose):
    fk = forward_kinematics(skel, pose)
    return np.asarray(fk.start, np.float64), np.asarray(fk.end, np.float64)


def test_swapped_legs_score_perfect_only_with_symmetry():
    skel = load_skeleton("spider")
    ts, te = _links(skel, rest_pose(skel, root_t=(0, 0, 1.0)))
    # rotate the spider by 90 degrees about its vertical: every leg lands on its neighbour's place
    ps, pe = _links(skel, rest_pose(skel, root_t=(0, 0, 1.0), root_rpy=(0, 0, np.pi / 2)))
    m = M.evaluate(ps, pe, ts, te, skel)
    assert m["strict"]["pcp"] < 0.5
    assert m["symmetric"]["pcp"] == 1.0 and m["symmetric"]["mpjpe_mm"] < 1e-3
    assert m["matching"]["leg0_upper"] != "leg0_upper"


@pytest.mark.parametrize("name", ["spider", "humanoid"])
def test_symmetric_never_worse_than_strict(name):
    skel = load_skeleton(name)
    rng = np.random.default_rng(1)
    ts, te = _links(skel, rest_pose(skel))
    for _ in range(10):
        noise = rng.normal(scale=0.08, size=(2,) + ts.shape)
        perm = rng.permutation(skel.num_links)
        ps, pe = (ts + noise[0])[perm], (te + noise[1])[perm]
        m = M.evaluate(ps, pe, ts, te, skel)
        for k in ("pcp", "pcp_10cm", "pck_10cm"):
            assert m["symmetric"][k] >= m["strict"][k]
        assert m["symmetric"]["mpjpe_mm"] <= m["strict"]["mpjpe_mm"]
    # without a skeleton, or with a trivial group, the two agree
    m = M.evaluate(ps, pe, ts, te)
    assert m["symmetric"] == m["strict"]


def test_evaluate_handles_large_groups_without_enumerating():
    links = [LinkSpec(f"leg{i}", length=0.2, radius=0.01) for i in range(12)]
    skel = build_skeleton("centipede", links)
    assert M.automorphism_group_order(skel) == 479001600
    with pytest.raises(ValueError):
        M.automorphisms(skel)
    ts, te = _links(skel, rest_pose(skel))
    te = te + np.arange(12)[:, None] * [0, 0.1, 0]
    perm = np.roll(np.arange(12), 5)
    m = M.evaluate(ts[perm], te[perm], ts, te, skel)
    assert m["symmetric"]["mpjpe_mm"] == pytest.approx(0.0, abs=1e-9)


# --------------------------------------------------------------------------- eval command


def _eval(argv):
    from jaxpose.commands import eval as eval_cmd

    parser = argparse.ArgumentParser(prog="jaxpose")
    eval_cmd.register(parser.add_subparsers())
    args = parser.parse_args(["eval", *argv])
    return args.func(args)


def _truth_file(path, skel, start, end, names=None):
    names = names or skel.link_names
    write_json(str(path), {
        "skeleton": {"name": skel.name, "file": skel.name},
        "links": [{"name": n, "parent": None, "start": s.tolist(), "end": e.tolist()}
                  for n, s, e in zip(names, start, end)],
    })


def test_eval_command_on_two_truth_files(tmp_path, capsys):
    skel = load_skeleton("spider")
    ts, te = _links(skel, rest_pose(skel, root_t=(0, 0, 1.0)))
    _truth_file(tmp_path / "truth.json", skel, ts, te)
    # the result lists the legs in another order and with leg0 and leg2 swapped
    names = list(skel.link_names)
    perm = [names.index(n.replace("leg0", "legX").replace("leg2", "leg0").replace("legX", "leg2")) for n in names]
    order = np.arange(len(names))[::-1]
    _truth_file(tmp_path / "result.json", skel, ts[perm][order], te[perm][order], [names[i] for i in order])
    assert _eval([str(tmp_path / "result.json"), str(tmp_path / "truth.json"), "--json"]) == 0
    m = json.loads(capsys.readouterr().out)
    assert m["symmetries"] == 24
    assert m["strict"]["pcp"] == pytest.approx(0.5)
    assert m["symmetric"]["pcp"] == 1.0 and m["symmetric"]["mpjpe_mm"] == pytest.approx(0, abs=1e-6)
    assert _eval([str(tmp_path / "truth.json"), str(tmp_path / "truth.json")]) == 0
    text = capsys.readouterr().out
    assert "24 symmetries" in text and "100.0%" in text
    _truth_file(tmp_path / "short.json", skel, ts[:3], te[:3], names[:3])
    with pytest.raises(JaxposeError, match="missing"):
        _eval([str(tmp_path / "short.json"), str(tmp_path / "truth.json")])
    with pytest.raises(JaxposeError, match="not found"):
        _eval([str(tmp_path / "nope.json"), str(tmp_path / "truth.json")])


def test_eval_command_leaves_links_of_zero_length_unscored(tmp_path, capsys):
    skel = load_skeleton("spider")
    ts, te = _links(skel, rest_pose(skel, root_t=(0, 0, 1.0)))
    te = te.copy()
    te[0] = ts[0]  # the body as a point (a sphere)
    _truth_file(tmp_path / "truth.json", skel, ts, te)
    assert _eval([str(tmp_path / "truth.json"), str(tmp_path / "truth.json")]) == 0
    text = capsys.readouterr().out
    assert "8 links, 24 symmetries (1 of length zero, not scored by PCP)" in text
    assert "misplaced" not in text  # the unscored body is not listed as misplaced
    names = list(skel.link_names)
    _truth_file(tmp_path / "points.json", skel, ts, ts, names)  # every link a point: no PCP at all
    assert _eval([str(tmp_path / "points.json"), str(tmp_path / "points.json"), "--json"]) == 0
    m = json.loads(capsys.readouterr().out)
    assert m["strict"]["pcp"] is None and m["symmetric"]["pcp"] is None and m["pcp_links"] == 0
    assert _eval([str(tmp_path / "points.json"), str(tmp_path / "points.json")]) == 0
    row = [line for line in capsys.readouterr().out.splitlines() if "half true length" in line][0]
    assert row.split()[-2:] == ["-", "-"]


def test_mirrored_hinge_legs_are_interchangeable():
    """The MJCF ant's legs bend about mirrored axes with negated limits: still interchangeable."""
    pytest.importorskip("mujoco")
    from jaxpose.metrics import automorphism_group_order

    ant = load_skeleton(os.path.join(os.path.dirname(__file__), "fixtures", "ant.xml"))
    assert automorphism_group_order(ant) == 24
