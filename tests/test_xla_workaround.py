"""The XLA:CPU YNNPACK workaround (jaxpose/_xla_flags.py).

jaxlib 0.10's YNNPACK fusions segfault in the memetic refinement batched over
islands (8 islands x 8 refined individuals, the defaults).  Each check runs in a
fresh interpreter, since XLA reads its flags once per process.
"""

import os
import subprocess
import sys
import textwrap

FIT = textwrap.dedent(
    """
    import jaxpose as jp  # first: applies the workaround before JAX computes anything
    import jax.numpy as jnp
    import numpy as np

    skel = jp.load_skeleton("spider")
    links = jp.forward_kinematics(skel, jp.rest_pose(skel, scale=1.0))
    rng = np.random.default_rng(0)
    k = rng.integers(0, skel.num_links, 512)
    t = rng.uniform(size=(512, 1))
    s, e = np.asarray(links.start), np.asarray(links.end)
    pts = s[k] + t * (e - s)[k] + np.array([0.0, 0.0, 2.0])
    cloud = jp.Cloud(jnp.asarray(pts, jnp.float32), jnp.ones(512, jnp.float32))
    # one epoch of 25 generations: a single compiled epoch with its memetic step (what crashed); one search, no sweeps
    cfg = jp.FitConfig(islands=8, population=16, generations=25, final_refine_steps=0, staged=0,
                       staged_alternatives=(), turns=0, limb_sweep=0, pivot_sweep=0)
    r = jp.fit_cloud(cloud, skel, 0, cfg)
    assert np.isfinite(float(r.cost)), r.cost
    print("FIT-OK", float(r.cost))
    """
)


def _python(code: str, env_extra: dict | None = None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env.update(env_extra or {})
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)


def test_import_sets_the_flag_once_and_keeps_a_users_setting():
    code = "import os, jaxpose; print(repr(os.environ.get('XLA_FLAGS')))"
    p = _python(code)
    assert p.returncode == 0, p.stderr
    import jaxlib

    if tuple(int(x) for x in jaxlib.__version__.split(".")[:2]) >= (0, 10):
        assert p.stdout.strip() == repr("--xla_cpu_experimental_ynn_fusion_type=")
    mine = "--xla_cpu_experimental_ynn_fusion_type=LIBRARY_FUSION_TYPE_DOT --xla_force_host_platform_device_count=1"
    p = _python(code, {"XLA_FLAGS": mine})
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == repr(mine)


def test_import_after_jax_started_warns():
    p = _python("import jax.numpy as jnp; jnp.zeros(1).block_until_ready()\nimport warnings\n"
                "warnings.simplefilter('error')\ntry:\n    import jaxpose\nexcept RuntimeWarning as w:\n"
                "    print('WARNED', w)\n")
    assert p.returncode == 0, p.stderr
    import jaxlib

    if tuple(int(x) for x in jaxlib.__version__.split(".")[:2]) >= (0, 10):
        assert "WARNED jaxpose: JAX's CPU backend started before jaxpose was imported" in p.stdout


def test_islands_with_memetic_refinement_do_not_crash():
    """Segfaulted (exit -11) on jaxlib 0.10.2 before the workaround."""
    p = _python(FIT)
    assert p.returncode == 0, (p.returncode, p.stderr[-2000:])
    assert "FIT-OK" in p.stdout
