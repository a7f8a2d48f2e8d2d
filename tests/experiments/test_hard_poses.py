"""The pure parts of experiments/hard_poses.py: the pose sampler and the diagnosis' verdicts (seconds)."""

from __future__ import annotations

import hard_poses as HP
import numpy as np
import pytest

import jaxpose


@pytest.fixture(scope="module")
def humanoid():
    return jaxpose.load_skeleton("humanoid")


def test_uniform_angles_cover_the_limits_and_stay_within(humanoid):
    rng = np.random.default_rng(0)
    draws = np.stack([HP.uniform_angles(humanoid, rng) for _ in range(400)])
    lo, hi = np.asarray(humanoid.angle_lo), np.asarray(humanoid.angle_hi)
    assert np.all(draws >= lo - 1e-12) and np.all(draws <= hi + 1e-12)
    span = hi - lo
    wide = span > 0.5  # the draws reach both ends of every wide range (uniform, not around the rest pose)
    assert np.all((draws.min(0) - lo)[wide] < 0.05 * span[wide])
    assert np.all((hi - draws.max(0))[wide] < 0.05 * span[wide])


def test_upright_within_the_tilt_and_any_yaw():
    rng = np.random.default_rng(1)
    rpys = [HP.upright_rpy(rng) for _ in range(300)]
    tilts = [HP.tilt_deg(r) for r in rpys]
    assert max(tilts) <= HP.MAX_TILT_DEG + 1e-6
    assert max(tilts) > 0.5 * HP.MAX_TILT_DEG
    yaws = np.array([r[2] for r in rpys])
    assert yaws.min() < -2.5 and yaws.max() > 2.5  # turned any way
    assert HP.tilt_deg(HP.upright_rpy(rng, yaw=1.0, max_tilt_deg=0.0)) == pytest.approx(0.0, abs=1e-6)


def test_hard_pose_within_limits_upright_and_not_interpenetrating(humanoid):
    rng = np.random.default_rng(2)
    scale, lengths = HP.subject_shape(humanoid, rng)
    assert 0.85 <= scale <= 1.1
    assert np.all(lengths >= np.asarray(humanoid.length_lo)) and np.all(lengths <= np.asarray(humanoid.length_hi))
    for kind in ("uniform", "natural"):
        pose, collision, tries = HP.hard_pose(humanoid, rng, kind, scale, lengths, max_tries=50)
        a = np.asarray(pose.angles)
        assert np.all(a >= np.asarray(humanoid.angle_lo) - 1e-6) and np.all(a <= np.asarray(humanoid.angle_hi) + 1e-6)
        assert HP.tilt_deg(np.asarray(pose.root_rpy)) <= HP.MAX_TILT_DEG + 1e-4
        assert collision <= HP.MAX_INTERPENETRATION or tries == 50
        assert np.allclose(np.asarray(pose.lengths), lengths, atol=1e-6)
    with pytest.raises(ValueError):
        HP.hard_pose(humanoid, rng, "folded")


def test_classify_on_hand_made_costs():
    assert HP.classify(0.080, 0.060) == "search"  # the truth is better: the search missed it
    assert HP.classify(0.060, 0.080) == "objective"  # the wrong pose is better: the objective's fault
    assert HP.classify(0.0610, 0.0600) == "objective"  # within the margin: not a better optimum
    assert HP.classify(0.0621, 0.0600) == "search"
    assert HP.classify(0.05, 0.05, margin=0.0) == "objective"


def test_link_tags():
    assert HP.link_tags(0.1, False, 0.0) == ["occluded"]
    assert HP.link_tags(0.9, True, 0.0) == ["swap"]
    assert HP.link_tags(0.9, False, 0.05) == ["interpenetrating"]
    assert HP.link_tags(0.2, True, 0.05) == ["occluded", "swap", "interpenetrating"]
    assert HP.link_tags(0.9, False, 0.0) == ["visible"]


def test_swapped_links_and_penetration(humanoid):
    from jaxpose.kinematics import forward_kinematics
    from jaxpose.skeleton import rest_pose

    links = forward_kinematics(humanoid, rest_pose(humanoid))
    s, e, r = (np.asarray(a, np.float64) for a in (links.start, links.end, links.radius))
    assert not HP.swapped_links(humanoid, s, e, s, e).any()
    names = humanoid.link_names
    li, ri = names.index("l_forearm"), names.index("r_forearm")
    ps, pe = s.copy(), e.copy()
    ps[li], pe[li] = s[ri], e[ri]  # the left forearm placed on the right one
    swapped = HP.swapped_links(humanoid, ps, pe, s, e)
    assert swapped[li] and swapped.sum() == 1
    assert HP.link_penetration(humanoid, s, e, r).max() < HP.PENETRATION
    pen = HP.link_penetration(humanoid, ps, pe, r)  # now it lies inside the right forearm's neighbours
    assert pen[li] > HP.PENETRATION


def test_summary_splits_search_and_objective_failures():
    def rec(image, pcp, found, truth, tags):
        links = [{"name": "a", "scored": True, "correct": not tags, "visible": 0.2 if "occluded" in tags else 0.9,
                  "tags": tags}, {"name": "b", "scored": True, "correct": True, "visible": 1.0, "tags": []}]
        return {"set": "s", "image": image, "pcp": pcp, "origins_10cm": pcp, "pck_10cm": pcp, "found_cost": found,
                "truth_cost": truth, "truth_clip_deviation_m": 0.0, "wall_seconds": 10.0,
                "verdict": HP.classify(found, truth) if tags else None, "links": links}

    s = HP.summarise([rec("i0", 1.0, 0.05, 0.05, []), rec("i1", 0.5, 0.09, 0.05, ["visible"]),
                      rec("i2", 0.5, 0.04, 0.05, ["occluded"])])["s"]
    assert (s["images"], s["perfect"], s["misses"]) == (3, 1, 2)
    assert s["split"]["search"]["images"] == 1 and s["split"]["objective"]["images"] == 1
    assert s["split"]["objective"]["tags"] == {"occluded": 1}
    assert s["visible_links"] == 5 and s["hidden_links"] == 1 and s["hidden_pcp"] == 0.0
    assert "| s | 3 |" in HP.markdown({"s": s})


def test_settings_reach_the_config_and_a_wrong_one_is_named():
    cfg = HP.config_with(HP.parse_settings(["islands=4", "objective.sigma_factor=0.5", "halve_islands_at=[0.5]"]))
    assert (cfg.islands, cfg.objective.sigma_factor, cfg.halve_islands_at) == (4, 0.5, (0.5,))
    for item, words in (("fit.islands=4", "--set fit.islands: not a FitConfig setting"),
                        ("objective.nothing=1", "--set objective.nothing: not a FitConfig setting"),
                        ("islands=0", "--set: islands must be >= 1")):
        with pytest.raises(SystemExit, match=words):
            HP.config_with(HP.parse_settings([item]))
