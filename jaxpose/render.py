"""Ray-cast depth rendering of capsules (pure JAX).

The camera sits at the origin looking along +z (x right, y down).  Every pixel's
ray is intersected analytically with every capsule (a cylinder with two
hemispherical caps); the nearest hit's z is the pixel's depth, 0 where nothing
is hit.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .camera import Intrinsics


def pixel_rays(k: Intrinsics) -> jax.Array:
    """Unit ray directions ``(H, W, 3)`` through the pixel centres."""
    v, u = jnp.meshgrid(jnp.arange(k.height, dtype=jnp.float32), jnp.arange(k.width, dtype=jnp.float32), indexing="ij")
    d = jnp.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, jnp.ones_like(u)], -1)
    return d / jnp.linalg.norm(d, axis=-1, keepdims=True)


def ray_capsule_distance(rd: jax.Array, pa: jax.Array, pb: jax.Array, r: jax.Array) -> jax.Array:
    """Distance along unit rays ``rd (..., 3)`` from the origin to a capsule (inf: miss)."""
    ro = jnp.zeros(3, rd.dtype)
    ba = pb - pa
    oa = ro - pa
    baba = jnp.dot(ba, ba)
    bard = rd @ ba
    baoa = jnp.dot(ba, oa)
    rdoa = rd @ oa
    oaoa = jnp.dot(oa, oa)
    a = baba - bard * bard
    b = baba * rdoa - baoa * bard
    c = baba * oaoa - baoa * baoa - r * r * baba
    h = b * b - a * c
    safe_a = jnp.where(jnp.abs(a) > 1e-12, a, 1e-12)
    t_body = (-b - jnp.sqrt(jnp.maximum(h, 0.0))) / safe_a
    y = baoa + t_body * bard
    body_hit = (h >= 0) & (jnp.abs(a) > 1e-12) & (y > 0) & (y < baba) & (t_body > 0)

    def sphere(centre):
        oc = ro - centre
        bb = rd @ oc
        cc = jnp.dot(oc, oc) - r * r
        hh = bb * bb - cc
        t = -bb - jnp.sqrt(jnp.maximum(hh, 0.0))
        return jnp.where((hh >= 0) & (t > 0), t, jnp.inf)

    t_caps = jnp.minimum(sphere(pa), sphere(pb))
    return jnp.where(body_hit, t_body, t_caps)


@jax.jit
def _render(rays, start, end, radius):
    def one(carry, cap):
        pa, pb, r = cap
        t = ray_capsule_distance(rays, pa, pb, r)
        t = jnp.where(r > 0, t, jnp.inf)
        return jnp.minimum(carry, t), None

    tmin, _ = jax.lax.scan(one, jnp.full(rays.shape[:-1], jnp.inf, rays.dtype), (start, end, radius))
    z = tmin * rays[..., 2]
    return jnp.where(jnp.isfinite(z), z, 0.0)


def render_capsules(start, end, radius, k: Intrinsics) -> jax.Array:
    """Depth image ``(H, W)`` in metres of capsules given in the camera frame (0: no hit)."""
    return _render(pixel_rays(k), jnp.asarray(start, jnp.float32), jnp.asarray(end, jnp.float32),
                   jnp.asarray(radius, jnp.float32))
