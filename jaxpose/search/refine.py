"""Gradient refinement of genomes with optax (the memetic step and the final polish)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax


def refine(loss_fn, genomes: jax.Array, steps: int, learning_rate: float) -> tuple[jax.Array, jax.Array]:
    """``steps`` Adam steps on each row of ``genomes (m, D)`` for ``loss_fn(genome) -> scalar``.

    Genes stay in ``[0, 1]`` (projected after every step).  Returns the refined
    genomes and their losses.  The best iterate of each row is kept, so refinement
    never makes an individual worse.
    """
    opt = optax.adam(learning_rate)
    value_and_grad = jax.vmap(jax.value_and_grad(loss_fn))

    def step(carry, _):
        g, opt_state, best_g, best_f = carry
        f, grad = value_and_grad(g)
        grad = jnp.where(jnp.isfinite(grad), grad, 0.0)
        better = f < best_f
        best_g = jnp.where(better[:, None], g, best_g)
        best_f = jnp.where(better, f, best_f)
        updates, opt_state = opt.update(grad, opt_state, g)
        g = jnp.clip(optax.apply_updates(g, updates), 0.0, 1.0)
        return (g, opt_state, best_g, best_f), None

    init = (genomes, opt.init(genomes), genomes, jnp.full(genomes.shape[:1], jnp.inf, genomes.dtype))
    (g, _, best_g, best_f), _ = jax.lax.scan(step, init, None, length=steps)
    f_last = jax.vmap(loss_fn)(g)
    better = f_last < best_f
    return jnp.where(better[:, None], g, best_g), jnp.where(better, f_last, best_f)
