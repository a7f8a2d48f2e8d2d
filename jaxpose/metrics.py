"""Pose accuracy metrics and skeleton symmetries (pure NumPy; no files).

Every metric compares predicted and true capsule end points, link by link
(``start``/``end`` arrays of shape ``(L, 3)``, metres, in the same order).

- **PCP** (percentage of correct parts, the paper's "links placed in the correct
  position"): a link is correct when *both* its end points lie within half of its
  *true* length of the true end points (:func:`pcp`).  Only links of positive true
  length are scored (:func:`pcp_scored`): a link of length zero (a sphere, or a
  robot file's frame without geometry, such as a tool frame or one joint of a
  multi-joint MJCF body) has no extent to measure its placement against; its end
  points still count in MPJPE and PCK.  ``pcp_10cm`` is the variant with a fixed
  10 cm radius, over every link.
- **MPJPE**: the mean distance between predicted and true end points, over the
  ``2 L`` link end points (starts and ends of every link; a joint shared by a
  parent's end and a child's start counts once for each link), in millimetres.
- **PCK@10cm**: the fraction of those ``2 L`` end points within 10 cm.

Symmetry.  Interchangeable parts (the spider's legs, a humanoid's left and right
limbs) cannot be told apart in a depth image, so an estimate with two legs
swapped is as good as the truth.  The skeleton's symmetries come from
:mod:`jaxpose.symmetry` (re-exported here).  Symmetric scores take, for every
metric separately, the best value over the whole group (computed exactly by
matching sibling subtrees bottom-up with the Hungarian algorithm, so large
groups are never enumerated); the strict scores use the identity only, so a
symmetric score is never worse than the strict one.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from .skeleton import Skeleton
from .symmetry import (  # noqa: F401  (re-exported: the metrics' symmetry API)
    _classes, _forms, _roots, automorphism_group_order, automorphisms, link_attributes, link_orbits,
)

PCK_THRESHOLD = 0.10  # metres
PCP_FRACTION = 0.5
MIN_PCP_LENGTH = 1e-6  # metres: shorter true links are not scored by PCP


# --------------------------------------------------------------------------- per-link metrics


def _arrays(*xs):
    out = [np.asarray(x, np.float64).reshape(-1, 3) for x in xs]
    if len({a.shape for a in out}) != 1:
        raise ValueError(f"start/end arrays differ in shape: {[a.shape for a in out]}")
    return out


def endpoint_errors(pred_start, pred_end, true_start, true_end) -> np.ndarray:
    """Distances ``(L, 2)`` between predicted and true starts and ends, metres."""
    ps, pe, ts, te = _arrays(pred_start, pred_end, true_start, true_end)
    return np.stack([np.linalg.norm(ps - ts, axis=-1), np.linalg.norm(pe - te, axis=-1)], -1)


def pcp_scored(true_start, true_end) -> np.ndarray:
    """Which links PCP scores ``(L,)``: those of positive true length (see the module docstring)."""
    ts, te = _arrays(true_start, true_end)
    return np.linalg.norm(te - ts, axis=-1) > MIN_PCP_LENGTH


def pcp(pred_start, pred_end, true_start, true_end, fraction: float = PCP_FRACTION) -> np.ndarray:
    """Per-link correctness ``(L,)``: both end points within ``fraction`` x the true length
    (never for a link of zero length; :func:`pcp_scored` says which links count)."""
    err = endpoint_errors(pred_start, pred_end, true_start, true_end)
    ts, te = _arrays(true_start, true_end)
    tol = fraction * np.linalg.norm(te - ts, axis=-1)
    return np.all(err <= tol[:, None], axis=-1) & pcp_scored(ts, te)


def pcp_abs(pred_start, pred_end, true_start, true_end, threshold: float = PCK_THRESHOLD) -> np.ndarray:
    """Per-link correctness ``(L,)``: both end points within ``threshold`` metres."""
    return np.all(endpoint_errors(pred_start, pred_end, true_start, true_end) <= threshold, axis=-1)


def mpjpe(pred_start, pred_end, true_start, true_end) -> float:
    """Mean end point error over the ``2 L`` link end points, millimetres."""
    return float(1000.0 * endpoint_errors(pred_start, pred_end, true_start, true_end).mean())


def pck(pred_start, pred_end, true_start, true_end, threshold: float = PCK_THRESHOLD) -> float:
    """Fraction of the ``2 L`` link end points within ``threshold`` metres of the truth."""
    return float((endpoint_errors(pred_start, pred_end, true_start, true_end) <= threshold).mean())


def _pair_costs(pred_start, pred_end, true_start, true_end) -> dict[str, np.ndarray]:
    """Cost of matching truth link ``i`` with predicted link ``j`` for every metric: ``(L, L)`` each."""
    ps, pe, ts, te = _arrays(pred_start, pred_end, true_start, true_end)
    ds = np.linalg.norm(ts[:, None] - ps[None], axis=-1)
    de = np.linalg.norm(te[:, None] - pe[None], axis=-1)
    tl = np.linalg.norm(te - ts, axis=-1)[:, None]
    scored = pcp_scored(ts, te)[:, None]
    return {
        "pcp": -((ds <= PCP_FRACTION * tl) & (de <= PCP_FRACTION * tl) & scored).astype(float),
        "pcp_10cm": -((ds <= PCK_THRESHOLD) & (de <= PCK_THRESHOLD)).astype(float),
        "mpjpe_mm": ds + de,
        "pck_10cm": -((ds <= PCK_THRESHOLD).astype(float) + (de <= PCK_THRESHOLD)),
    }


def scores(pred_start, pred_end, true_start, true_end) -> dict[str, float | None]:
    """All four metrics for links given in matching order (``pcp`` is ``None`` when no link has a length)."""
    scored = pcp_scored(true_start, true_end)
    correct = pcp(pred_start, pred_end, true_start, true_end)
    return {
        "pcp": float(correct[scored].mean()) if scored.any() else None,
        "pcp_10cm": float(pcp_abs(pred_start, pred_end, true_start, true_end).mean()),
        "mpjpe_mm": mpjpe(pred_start, pred_end, true_start, true_end),
        "pck_10cm": pck(pred_start, pred_end, true_start, true_end),
    }


# --------------------------------------------------------------------------- symmetric matching


def best_matching(skel: Skeleton, cost: np.ndarray) -> np.ndarray:
    """The symmetry ``perm (L,)`` minimising ``sum_i cost[i, perm[i]]`` (exact, without enumeration).

    ``cost[i, j]``: cost of matching true link ``i`` with predicted link ``j``.
    """
    cost = np.asarray(cost, np.float64)
    form = _forms(skel)
    children = skel.children
    memo: dict = {}

    def sub(u, v):
        """Best cost and mapping of subtree ``u`` onto the alike subtree ``v``."""
        if (u, v) not in memo:
            c, m = match(children[u], children[v])
            memo[(u, v)] = (cost[u, v] + c, {u: v, **m})
        return memo[(u, v)]

    def match(cu, cv):
        total, mapping = 0.0, {}
        for cls_u, cls_v in zip(_classes(cu, form), _classes(cv, form)):
            if len(cls_u) == 1:
                c, m = sub(cls_u[0], cls_v[0])
                total += c
                mapping.update(m)
                continue
            C = np.array([[sub(a, b)[0] for b in cls_v] for a in cls_u])
            rows, cols = linear_sum_assignment(C)
            for r_, c_ in zip(rows, cols):
                c, m = sub(cls_u[r_], cls_v[c_])
                total += c
                mapping.update(m)
        return total, mapping

    roots = _roots(skel)
    _, mapping = match(roots, roots)
    return np.array([mapping[i] for i in range(skel.num_links)], np.int64)


# --------------------------------------------------------------------------- evaluation


def evaluate(
    pred_start, pred_end, true_start, true_end, skel: Skeleton | None = None, names=None
) -> dict:
    """Strict and symmetry-aware scores of a predicted pose against the truth.

    Links are in the same order in all arrays (the skeleton's order when ``skel``
    is given).  Returns ``{"num_links", "pcp_links", "symmetries", "strict": {...},
    "symmetric": {...}, "per_link": {...}, "matching": {...}}`` where each score
    block holds ``pcp``, ``pcp_10cm``, ``pck_10cm`` (fractions) and ``mpjpe_mm``;
    ``pcp_links`` is the number of links PCP scores (positive true length), and a
    link it does not score has ``"correct": None``.  Without a skeleton the
    symmetric block equals the strict one.
    """
    ps, pe, ts, te = _arrays(pred_start, pred_end, true_start, true_end)
    L = len(ts)
    if skel is not None and skel.num_links != L:
        raise ValueError(f"skeleton {skel.name!r} has {skel.num_links} links, the poses have {L}")
    names = list(names) if names is not None else (list(skel.link_names) if skel is not None else
                                                   [str(i) for i in range(L)])
    strict = scores(ps, pe, ts, te)
    sym = dict(strict)
    matching = np.arange(L)
    if skel is not None:
        costs = _pair_costs(ps, pe, ts, te)
        for metric, C in costs.items():
            perm = best_matching(skel, C)
            s = scores(ps[perm], pe[perm], ts, te)[metric]
            if s is None:  # PCP with no link of positive length
                continue
            # the identity is in the group, so the best is never worse than the strict value
            sym[metric] = min(s, strict[metric]) if metric == "mpjpe_mm" else max(s, strict[metric])
            if metric == "mpjpe_mm":
                matching = perm
    err = endpoint_errors(ps, pe, ts, te)
    per_link = {
        n: {"correct": bool(c) if k else None, "start_error_mm": float(1000 * e[0]), "end_error_mm": float(1000 * e[1])}
        for n, c, k, e in zip(names, pcp(ps, pe, ts, te), pcp_scored(ts, te), err)
    }
    return {
        "num_links": L,
        "pcp_links": int(pcp_scored(ts, te).sum()),
        "symmetries": automorphism_group_order(skel) if skel is not None else 1,
        "strict": strict,
        "symmetric": sym,
        "per_link": per_link,
        "matching": {names[i]: names[int(j)] for i, j in enumerate(matching)},
    }
