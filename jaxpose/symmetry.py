"""Symmetries of a skeleton (pure NumPy; no files): which links are interchangeable.

Interchangeable parts (the spider's legs, a humanoid's left and right limbs)
cannot be told apart in a depth image.  :func:`automorphisms` finds every
permutation of the links that maps the tree onto itself (parents onto parents)
and keeps each link's *attributes*: joint type, joint limits, length and length
range, radius and ``attach``.  The anchor offsets, rest rotations, hinge axes and
segment directions are *not* attributes: they say where a part sits, not what it
is (the spider's legs differ only in them).  :func:`link_orbits` groups the links
that some symmetry maps onto each other.  The metrics score the best matching
over the group (:func:`jaxpose.metrics.best_matching`); the search can give the
links of one orbit one length (``FitConfig.tie_lengths``).
"""

from __future__ import annotations

import itertools
import math
from collections import defaultdict

import numpy as np

from .skeleton import JOINT_DOF, Skeleton


def link_attributes(skel: Skeleton, decimals: int = 5) -> list[tuple]:
    """What makes a link the kind of link it is (see the module docstring), rounded for comparison."""
    r = lambda a: tuple(np.round(np.asarray(a, np.float64), decimals).reshape(-1).tolist())  # noqa: E731
    out = []
    for i, jt in enumerate(skel.joint_types):
        dof = JOINT_DOF[jt]
        lo, hi = r(np.asarray(skel.angle_lo)[i, :dof]), r(np.asarray(skel.angle_hi)[i, :dof])
        if jt in ("hinge", "slide"):  # about / along -axis with negated limits: the same poses; mirrored legs match
            lo, hi = min((lo, hi), (r(-np.asarray(hi)), r(-np.asarray(lo))))
        out.append((
            jt,
            lo, hi,
            r(np.asarray(skel.length)[i]), r(np.asarray(skel.length_lo)[i]), r(np.asarray(skel.length_hi)[i]),
            r(np.asarray(skel.radius)[i]), r(np.asarray(skel.attach)[i]),
        ))
    return out


def _forms(skel: Skeleton) -> list[int]:
    """Canonical isomorphism class of every link's subtree (equal ids: interchangeable subtrees)."""
    attrs = link_attributes(skel)
    children = skel.children
    table: dict = {}
    form = [0] * skel.num_links
    for i in reversed(range(skel.num_links)):  # children come after their parents
        key = (attrs[i], tuple(sorted(form[c] for c in children[i])))
        form[i] = table.setdefault(key, len(table))
    return form


def _roots(skel: Skeleton) -> tuple[int, ...]:
    return tuple(i for i, p in enumerate(skel.parents) if p < 0)


def _classes(nodes, form) -> list[list[int]]:
    groups = defaultdict(list)
    for n in nodes:
        groups[form[n]].append(n)
    return [groups[f] for f in sorted(groups)]


def automorphism_group_order(skel: Skeleton) -> int:
    """Number of symmetries of the skeleton: product over nodes of ``k!`` per class of ``k`` alike children."""
    form = _forms(skel)
    order = 1
    for nodes in [_roots(skel), *skel.children]:
        for cls in _classes(nodes, form):
            order *= math.factorial(len(cls))
    return order


def automorphisms(skel: Skeleton, limit: int = 100_000) -> np.ndarray:
    """Every symmetry as a permutation ``perm (G, L)``: link ``i`` maps onto link ``perm[g, i]``.

    The identity comes first.  Raises ``ValueError`` when there are more than ``limit``.
    """
    order = automorphism_group_order(skel)
    if order > limit:
        raise ValueError(f"skeleton {skel.name!r} has {order} symmetries, more than the limit of {limit}")
    form = _forms(skel)
    children = skel.children

    def iso(pairs):
        """All extensions of a list of (u, v) subtree pairs to full mappings (lists of dicts)."""
        if not pairs:
            return [{}]
        (u, v), rest = pairs[0], pairs[1:]
        out = []
        for sub in _match_children(children[u], children[v]):
            for tail in iso(rest):
                out.append({u: v, **sub, **tail})
        return out

    def _match_children(cu, cv):
        options = [{}]
        for cls_u, cls_v in zip(_classes(cu, form), _classes(cv, form)):
            new = []
            for perm in _permutations(cls_v):
                for m in iso(list(zip(cls_u, perm))):
                    for o in options:
                        new.append({**o, **m})
            options = new
        return options

    roots = _roots(skel)
    maps = _match_children(roots, roots)
    perms = np.array([[m[i] for i in range(skel.num_links)] for m in maps], np.int64).reshape(-1, skel.num_links)
    ident = np.arange(skel.num_links)
    is_id = np.all(perms == ident, axis=1)
    return np.concatenate([perms[is_id], perms[~is_id]], 0)


def _permutations(items):
    return list(itertools.permutations(items))


def link_orbits(skel: Skeleton) -> list[tuple[int, ...]]:
    """Sets of links that some symmetry maps onto each other (e.g. the four spider thighs)."""
    form = _forms(skel)
    key: list = []
    for i, p in enumerate(skel.parents):
        key.append((form[i], key[p] if p >= 0 else None))
    groups = defaultdict(list)
    for i, k in enumerate(key):
        groups[k].append(i)
    return sorted((tuple(g) for g in groups.values()), key=lambda g: g[0])
