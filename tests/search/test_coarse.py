"""Coarse-to-fine scoring (:mod:`jaxpose.search.coarse`)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from search_cases import COARSE, N_POINTS, OBJ, skeleton, spider_cloud

import jaxpose
from jaxpose import Cloud, forward_kinematics, observe, population_cost
from jaxpose.objective import spread_order
from jaxpose.search.coarse import coarse_switch, rescore_at_switch
from jaxpose.search.compiled import generations_jit, init_jit, refine_jit
from jaxpose.search.memetic import memetic_apply


def test_coarse_to_fine_scores_leading_blocks_then_rescores_everything():
    skel, cloud = skeleton(), spider_cloud()
    assert coarse_switch(COARSE, N_POINTS) == 2
    assert coarse_switch(dataclasses.replace(COARSE, coarse_points=100), N_POINTS) is None  # 2 blocks: all
    obs = observe(cloud, OBJ)
    first = spread_order(N_POINTS)[:64]
    coarse_cloud = Cloud(cloud.points[first], cloud.weights[first])

    def costs(st, c):  # every island's population scored from scratch on cloud c
        out = []
        for i in range(COARSE.islands):
            poses = jax.vmap(lambda g: jaxpose.decode(skel, st.bounds, g))(st.algo_state.population[i])
            links = jax.vmap(lambda p: forward_kinematics(skel, p))(poses)
            o = observe(c, OBJ)._replace(sigma=obs.sigma, fmap=obs.fmap)
            out.append(np.asarray(population_cost(o, links.start, links.end, links.radius, OBJ)))
        return np.stack(out)

    static, params = COARSE.static(), COARSE.params()
    st = init_jit(cloud, skel, jax.random.key(1), config=static, params=params)
    st, _ = generations_jit(skel, static, st, 2)  # before the switch: scored on the coarse cloud
    np.testing.assert_allclose(np.asarray(st.algo_state.fitness), costs(st, coarse_cloud), rtol=2e-5)
    st, _ = memetic_apply(skel, static, st, refine_jit(skel, static, st, 3, jnp.int32(2)), jnp.zeros(2))
    after = rescore_at_switch(skel, static, st)
    np.testing.assert_allclose(np.asarray(after.algo_state.fitness), costs(after, cloud), rtol=2e-5)
    assert not np.allclose(np.asarray(st.algo_state.fitness), np.asarray(after.algo_state.fitness))
    np.testing.assert_array_equal(np.asarray(after.objective_evaluations - st.objective_evaluations),
                                  COARSE.population + 1)
