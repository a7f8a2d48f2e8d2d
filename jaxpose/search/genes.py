"""Which genes are searched when (staged search) and alike links' tied lengths."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..genome import Bounds, encode, genome_layout
from ..skeleton import Skeleton, rest_pose
from .config import FitConfig


def gene_levels(skel: Skeleton) -> np.ndarray:
    """Tree depth of every gene's link (-1 for the root genes)."""
    depth = np.zeros(skel.num_links, np.int32)
    for d, level in enumerate(skel.levels):
        depth[list(level)] = d
    link = np.asarray(genome_layout(skel).link_of_gene)
    return np.where(link >= 0, depth[np.maximum(link, 0)], -1)


def unlocked(skel: Skeleton, config: FitConfig, generation, staged=None) -> jax.Array:
    """Boolean ``(D,)``: the genes searched at ``generation`` (``staged``, traced, default
    ``config.staged``: links at depth ``d`` join after ``d / levels`` of the staged phase;
    0: every gene at once)."""
    levels = jnp.asarray(gene_levels(skel))
    staged = config.staged if staged is None else staged
    phase = staged * config.generations / len(skel.levels)
    return (levels <= jnp.floor(generation / jnp.where(phase > 0, phase, 1.0))) | (phase <= 0)


def length_orbits(skel: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """Genes of searched lengths that alike links share (``Skeleton.orbit``), and each
    one's orbit number: ``(genes (T,), orbit (T,))``, empty when there are none."""
    length_gene, length_link = genome_layout(skel).length_genes()
    gene_of = dict(zip(length_link.tolist(), length_gene.tolist()))
    members: dict[int, list[int]] = {}
    for i, o in enumerate(skel.orbit):
        if i in gene_of:
            members.setdefault(o, []).append(gene_of[i])
    tied = [m for m in members.values() if len(m) > 1]
    genes = [g for m in tied for g in m]
    orbit = [k for k, m in enumerate(tied) for _ in m]
    return np.asarray(genes, np.int32), np.asarray(orbit, np.int32)


def tie_lengths(skel: Skeleton, genomes):
    """Length genes of alike links (a humanoid's two forearms, a spider's legs) set to their mean."""
    genes, orbit = length_orbits(skel)
    if genes.size == 0:
        return genomes
    one_hot = jnp.asarray(orbit[:, None] == np.arange(orbit.max() + 1)[None], genomes.dtype)
    mean = (genomes[..., genes] @ one_hot) / jnp.sum(one_hot, 0)
    return genomes.at[..., genes].set(mean[..., orbit])


def lock(skel: Skeleton, config: FitConfig, bounds: Bounds, generation, genomes, staged):
    """Genes locked at ``generation`` (staged search; ``staged``: the traced
    :attr:`FitParams.staged`) set to their rest values; with ``tie_lengths`` the
    length genes of alike links set to their mean."""
    if config.tie_lengths:
        genomes = tie_lengths(skel, genomes)
    rest = encode(skel, bounds, rest_pose(skel))
    return jnp.where(unlocked(skel, config, generation, staged), genomes, rest)
