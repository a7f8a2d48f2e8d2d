"""The search's cost and its gradient on the spider, for tests/test_xla_settings.py: computed
in the test's process and, run as ``python xla_probe.py OUT.npz``, in a fresh interpreter."""

from __future__ import annotations

import sys


def probe() -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    import jaxpose as jp
    from jaxpose.objective import ObjectiveConfig
    from jaxpose.search.cost import pose_cost

    skel = jp.load_skeleton("spider")
    rng = np.random.default_rng(0)
    rest = jp.rest_pose(skel, root_t=(0.0, 0.1, 1.2), root_rpy=(-2.2, 0.0, 0.3))
    lo, hi = np.asarray(skel.angle_lo), np.asarray(skel.angle_hi)
    truth = rest._replace(angles=jnp.asarray(rng.uniform(lo, hi) * 0.5, jnp.float32))
    links = jp.forward_kinematics(skel, truth)
    s, e = np.asarray(links.start), np.asarray(links.end)
    k, t = rng.integers(0, skel.num_links, 1500), rng.uniform(size=(1500, 1))
    points = s[k] + t * (e - s)[k] + 0.02 * rng.standard_normal((1500, 3))
    obs = jp.observe(jp.Cloud(jnp.asarray(points, jnp.float32), jnp.ones(1500, jnp.float32)))
    P = 32  # poses about the truth: angles and root moved
    poses = jax.tree_util.tree_map(lambda x: jnp.repeat(x[None], P, 0), truth)
    poses = poses._replace(angles=poses.angles + jnp.asarray(rng.normal(0, 0.3, poses.angles.shape), jnp.float32),
                           root_t=poses.root_t + jnp.asarray(rng.normal(0, 0.05, poses.root_t.shape), jnp.float32))
    obj = ObjectiveConfig()
    cost = jax.jit(lambda p: pose_cost(skel, obs, p, obj))
    grad = jax.jit(jax.grad(lambda p: jnp.sum(pose_cost(skel, obs, p, obj))))
    g = grad(poses)
    return {"cost": np.asarray(cost(poses)), "grad_angles": np.asarray(g.angles), "grad_root_t": np.asarray(g.root_t)}


if __name__ == "__main__":
    import numpy as np

    np.savez(sys.argv[1], **probe())
