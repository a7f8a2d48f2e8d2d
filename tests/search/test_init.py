"""Where the search starts (:mod:`jaxpose.search.init`, :mod:`jaxpose.rest_model`):
the rest model's spin axis, the aligned and spun root hypotheses, the initial population."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from search_cases import GA, OBJ, capsule_surface_cloud, skeleton, spider_cloud, true_pose

from jaxpose import forward_kinematics, genome_layout, observe
from jaxpose.genome import decode
from jaxpose.geometry import matrix_to_rpy, rpy_matrix
from jaxpose.rest_model import ELONGATED, model_samples, rest_model
from jaxpose.search import initial_population
from jaxpose.search.init import aligned_root, search_bounds


@pytest.mark.parametrize("name,axis", [("humanoid", 0), ("snake", 0), ("spider", 2)])
def test_rest_model_spins_about_the_major_axis_of_elongated_models_else_the_normal(name, axis):
    skel = skeleton(name)
    rest = rest_model(skel)
    pts = np.asarray(model_samples(skel), np.float64)
    var = np.sort(np.linalg.eigvalsh(np.cov(pts.T, bias=True)))[::-1]  # NumPy oracle
    assert (var[0] >= ELONGATED * var[1]) == (axis == 0)
    assert int(rest.spin_axis) == axis
    np.testing.assert_allclose(float(rest.spread), np.sqrt(((pts - pts.mean(0)) ** 2).sum(1).mean()), rtol=1e-5)


@pytest.mark.parametrize("name", ["humanoid", "spider"])
def test_spun_hypotheses_keep_the_spin_axis_and_turn_about_it(name):
    """aligned_root(spin=a) = Rot(cloud axis, a) @ aligned_root(spin=0): the model's spin
    axis stays on the cloud's, and the model's centroid stays on the same spot."""
    from jaxpose.geometry import rpy_matrix

    skel = skeleton(name)
    links = forward_kinematics(skel, true_pose(skel))
    cloud = capsule_surface_cloud(links.start, links.end, links.radius, 400, 1)
    obs = observe(cloud, OBJ)
    rest = rest_model(skel)
    k = int(rest.spin_axis)
    pts = np.asarray(cloud.points, np.float64)
    _, v = np.linalg.eigh(np.cov(pts.T, bias=True))
    c_axis = v[:, ::-1][:, k]  # NumPy oracle of the cloud's axis
    m_axis = np.asarray(rest.axes)[:, k]
    m_c = np.asarray(rest.centre)
    for flip in ([False, False], [True, False]):
        t0, rpy0 = aligned_root(jnp.asarray(flip), skel, obs, 1.3, rest)
        R0 = np.asarray(rpy_matrix(np.asarray(rpy0, np.float64)))
        centroid = np.asarray(t0) + 1.3 * R0 @ m_c
        for a in (0.7, 2.0, -2.9):
            t, rpy = aligned_root(jnp.asarray(flip), skel, obs, 1.3, rest, a)
            R = np.asarray(rpy_matrix(np.asarray(rpy, np.float64)))
            assert abs(abs(R @ m_axis @ c_axis) - 1) < 1e-4  # the spin axis lies on the cloud's
            turn = R @ R0.T  # a rotation by a about the cloud's axis (Rodrigues, by hand)
            K = np.array([[0, -c_axis[2], c_axis[1]], [c_axis[2], 0, -c_axis[0]], [-c_axis[1], c_axis[0], 0]])
            np.testing.assert_allclose(turn, np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K, atol=2e-4)
            np.testing.assert_allclose(np.asarray(t) + 1.3 * R @ m_c, centroid, atol=1e-4)


def test_initial_population_lies_in_the_unit_box_and_takes_the_traced_spreads():
    """FitConfig: the non-aligned fraction's root translation genes spread by
    ``init_root_std`` around the cloud's centre (gene 0.5), the aligned fraction
    (``init_pca_fraction``, the first rows) by ``init_pca_std`` around its hypotheses."""
    skel, cloud = skeleton(), spider_cloud()
    obs = observe(cloud, OBJ)
    config = dataclasses.replace(GA, init_pca_fraction=0.25)
    bounds = search_bounds(skel, obs, config)
    key = jax.random.key(4)

    def population(**kw):
        cfg = dataclasses.replace(config, **kw)
        return np.asarray(initial_population(key, skel, obs, bounds, cfg.static(), cfg.params()))

    pop = population()
    P, D = config.population, genome_layout(skel).size
    assert pop.shape == (P, D) and pop.min() >= 0.0 and pop.max() <= 1.0
    n_pca = round(0.25 * P)
    root_t = slice(0, 3)
    # no spread: the other rows' root translation genes are the centre, the aligned rows' roots
    # are their noiseless hypotheses (the same draw of flips and spins whatever the spread)
    still = population(init_root_std=0.0, init_pca_std=0.0)
    np.testing.assert_array_equal(still[n_pca:, root_t], 0.5)
    assert np.std(pop[n_pca:, root_t]) > 0.02
    moved = population(init_pca_std=0.1)
    diff = moved[:n_pca, :6] - still[:n_pca, :6]
    assert np.any(np.abs(diff) > 1e-3)
    np.testing.assert_array_equal(moved[n_pca:], pop[n_pca:])  # the aligned spread touches the aligned rows only


def test_a_turn_searchs_aligned_starts_keep_their_orientation_inside_the_window():
    """With the root held (a turn search: genes relative to ``root_rpy``), an aligned start whose
    orientation lies inside the window decodes to that same orientation, and every start lies
    within the window: the aligned orientations are converted to relative genes, not clipped
    as absolute angles."""
    skel, cloud = skeleton("humanoid"), spider_cloud()
    obs = observe(cloud, OBJ)
    config = dataclasses.replace(GA, init_pca_fraction=0.5, init_pca_std=0.0)
    key = jax.random.key(7)
    free_params = config.params()
    free = search_bounds(skel, obs, config, params=free_params)
    start = initial_population(key, skel, obs, free, config.static(), free_params)
    aligned = rpy_matrix(decode(skel, free, start[0]).root_rpy)  # the first aligned start, free
    window = 0.3
    params = free_params.replace(root_rpy=matrix_to_rpy(aligned), root_window=jnp.float32(window))
    held = search_bounds(skel, obs, config, params=params)
    pop = initial_population(key, skel, obs, held, config.static(), params)
    R = np.stack([np.asarray(rpy_matrix(decode(skel, held, g).root_rpy), np.float64) for g in pop])
    np.testing.assert_allclose(R[0], np.asarray(aligned, np.float64), atol=1e-5)
    A = np.asarray(aligned, np.float64)
    angle = np.degrees(np.arccos(np.clip((np.einsum("pij,ij->p", R, A) - 1) / 2, -1, 1)))
    assert angle.max() <= np.degrees(3 * window) + 1e-3  # a turn of at most `window` about each axis
    assert angle.max() > 5  # the window is used, not collapsed


@pytest.mark.parametrize("scale", [0.7, 1.0, 2.5])  # 2.5: outside the spider's own range, as a user may know
def test_a_known_scale_is_the_scale_genes_one_value(scale):
    skel, cloud = skeleton(), spider_cloud()
    cfg = dataclasses.replace(GA, scale=scale)
    obs = observe(cloud, OBJ)
    b = search_bounds(skel, obs, cfg)
    i = genome_layout(skel).names.index("scale")
    assert float(b.lo[i]) == float(b.hi[i]) == np.float32(scale)
    free = search_bounds(skel, obs, GA)  # every other gene as without it
    others = np.arange(b.lo.shape[0]) != i
    np.testing.assert_array_equal(np.asarray(b.lo)[others], np.asarray(free.lo)[others])
    np.testing.assert_array_equal(np.asarray(b.hi)[others], np.asarray(free.hi)[others])
    pop = initial_population(jax.random.key(0), skel, obs, b, cfg, cfg.params())
    poses = jax.vmap(lambda g: decode(skel, b, g))(pop)
    np.testing.assert_array_equal(np.asarray(poses.scale), np.float32(scale))


def test_a_fit_with_a_known_scale_returns_it_and_bad_values_are_refused():
    from jaxpose.errors import ConfigError
    from jaxpose.search import fit_cloud

    r = fit_cloud(spider_cloud(), skeleton(), 0, dataclasses.replace(GA, scale=0.9))
    assert float(r.pose.scale) == np.float32(0.9)
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="scale"):
            dataclasses.replace(GA, scale=bad).validate()
