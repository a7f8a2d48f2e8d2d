"""The collision term: a body's parts do not pass through each other (see :mod:`jaxpose.objective`)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..geometry import closest_points


class CollisionPairs(NamedTuple):
    """Capsule pairs the collision term checks: link indices ``i, j`` (static NumPy
    ``(K,)``) and ``rho (K,)``, the fraction of the clearance each pair must keep."""

    i: np.ndarray
    j: np.ndarray
    rho: jax.Array


def collision_cost(pairs: CollisionPairs, sigma, start, end, radius, margin: float) -> jax.Array:
    """Collision penalty ``(P,)`` of posed capsules ``start, end (P, L, 3)``, ``radius (P, L)``
    (see the module docstring).

    Reverse-mode derivatives come from a custom VJP: the distance of two segments
    changes with their ends as the distance of their closest points does (the
    closest points' parameters are a minimum, so their own change does not count),
    and the pairs' gradients go back to the links by products with constant 0/1
    matrices.  Same values as differentiating the arithmetic (to round-off), and a
    smaller program to compile than the backward pass of every clamp and gather.
    Reverse mode only (``jax.grad``, ``jax.vjp``): forward-mode derivatives
    (``jax.jvp``, ``jax.jacfwd``, ``jax.hessian``) of the term raise.  ``sigma`` and
    ``margin`` are scalars or one per individual ``(P,)``.
    """
    if len(pairs.i) == 0:  # (population_cost leaves the term out then)
        return jnp.zeros(start.shape[:1], start.dtype)
    # link-major coordinates (3, L, P): the pairs' gathers pick whole rows
    s, e = jnp.transpose(start, (2, 1, 0)), jnp.transpose(end, (2, 1, 0))
    r = jnp.broadcast_to(jnp.asarray(radius, start.dtype), start.shape[:-1]).T
    i, j = (k if isinstance(k, (np.ndarray, jax.Array)) else np.asarray(k, np.int32) for k in (pairs.i, pairs.j))
    penalty = _pair_penalty(i, j, start.shape[1], start.dtype)
    return penalty(s, e, r, jnp.asarray(pairs.rho, start.dtype), jnp.asarray(sigma, start.dtype),
                   jnp.asarray(margin, start.dtype))


def _pair_penalty(i, j, L: int, dtype):
    """``penalty(s, e (3, L, P), r (L, P), rho (K,), sigma, margin) -> (P,)`` for the
    pairs ``i, j (K,)`` (static or traced)."""
    to_i = (jnp.arange(L)[:, None] == i[None, :]).astype(dtype)  # (L, K): pair k -> link i[k]
    to_j = (jnp.arange(L)[:, None] == j[None, :]).astype(dtype)

    def forward(s, e, r, rho, sigma, margin):
        d, u, v, diff = closest_points(s[:, i], e[:, i], s[:, j], e[:, j], xp=jnp)  # (K, P), (3, K, P)
        reach = rho[:, None] * (r[i] + r[j])
        h = jnp.maximum(margin * reach - d, 0.0)
        return jnp.sum(jnp.log1p(h / sigma), 0), (d, u, v, diff, h, reach, rho, r, sigma, margin)

    def backward(res, g):
        d, u, v, diff, h, reach, rho, r, sigma, margin = res
        dh = jnp.where(margin * reach > d, g / (sigma + h), 0.0)  # d penalty / d clearance, (K, P)
        n = diff * (-dh / d)  # d penalty / d (closest point on i)
        links = lambda M, x: jnp.einsum("lk,...kp->...lp", M, x)  # noqa: E731
        g_s = links(to_i, n * (1.0 - u)) - links(to_j, n * (1.0 - v))
        g_e = links(to_i, n * u) - links(to_j, n * v)
        g_r = links(to_i + to_j, dh * rho[:, None] * margin)
        g_rho = jnp.sum(dh * margin * (r[i] + r[j]), 1)
        g_sigma = -g * jnp.sum(h / (sigma * (sigma + h)), 0)  # (P,)
        return g_s, g_e, g_r, g_rho, _sum_to(g_sigma, sigma.shape), _sum_to(jnp.sum(dh * reach, 0), margin.shape)

    penalty = jax.custom_vjp(lambda *a: forward(*a)[0])
    penalty.defvjp(forward, backward)
    return penalty


def _sum_to(x, shape):
    """``x (P,)`` summed to a scalar argument's ``shape`` (``()``), or kept for one per individual."""
    return x.reshape(shape) if x.shape == tuple(shape) else jnp.sum(x).reshape(shape)
