"""Gradient refinement of genomes with optax (the memetic step and the final polish)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax


def refine(population_loss, genomes: jax.Array, steps, learning_rate: float) -> tuple[jax.Array, jax.Array]:
    """Adam on each row of ``genomes (m, D)``: ``steps`` evaluations of the loss and
    its gradient, at the start and after each of the first ``steps - 1`` updates.

    ``population_loss(genomes (m, D)) -> (m,)`` scores rows independently (a
    population cost), so the gradient of its sum is every row's own gradient.
    ``steps`` may be a traced integer: one compiled program serves any count.
    Genes stay in ``[0, 1]`` (projected after every step).  Returns the best
    evaluated iterate of each row and its loss, so refinement never makes an
    individual worse (the start is the first iterate).  The last update is not
    taken: scoring it would need a forward-only copy of the loss in the program,
    which costs more to compile than the step is worth.  (``steps = 0``: the rows
    come back unchanged, with loss ``+inf``.)
    """
    opt = optax.adam(learning_rate)

    def total(g):
        f = population_loss(g)
        return jnp.sum(jnp.where(jnp.isfinite(f), f, 0.0)), f

    value_and_grad = jax.value_and_grad(total, has_aux=True)

    def step(_, carry):
        g, opt_state, best_g, best_f = carry
        (_, f), grad = value_and_grad(g)
        grad = jnp.where(jnp.isfinite(grad), grad, 0.0)
        better = f < best_f
        best_g = jnp.where(better[:, None], g, best_g)
        best_f = jnp.where(better, f, best_f)
        updates, opt_state = opt.update(grad, opt_state, g)
        g = jnp.clip(optax.apply_updates(g, updates), 0.0, 1.0)
        return g, opt_state, best_g, best_f

    init = (genomes, opt.init(genomes), genomes, jnp.full(genomes.shape[:1], jnp.inf, genomes.dtype))
    _, _, best_g, best_f = jax.lax.fori_loop(0, steps, step, init)
    return best_g, best_f
