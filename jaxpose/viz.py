"""Plots (optional extra ``viz``: matplotlib)."""

from __future__ import annotations

import numpy as np

from .camera import Intrinsics, project
from .errors import ConfigError


def _pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise ConfigError("plotting needs matplotlib: pip install 'jaxpose[viz]'") from None
    return plt


def overlay_figure(depth: np.ndarray, k: Intrinsics, links: list[dict], title: str = "",
                   truth: list[dict] | None = None):
    """Figure: the depth image with the fitted capsule axes projected on it."""
    plt = _pyplot()
    h, w = depth.shape
    fig, ax = plt.subplots(figsize=(w / 100, h / 100), dpi=100)
    shown = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)
    ax.imshow(shown, cmap="gray_r")
    cmap = plt.get_cmap("tab20")
    for i, link in enumerate(links):
        uv = project(np.array([link["start"], link["end"]]), k)
        ax.plot(uv[:, 0], uv[:, 1], "-", color=cmap(i % 20), lw=3, solid_capstyle="round")
        ax.plot(uv[0, 0], uv[0, 1], "o", color=cmap(i % 20), ms=4)
    if truth:
        for link in truth:
            uv = project(np.array([link["start"], link["end"]]), k)
            ax.plot(uv[:, 0], uv[:, 1], "--", color="k", lw=1)
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=8)
    fig.tight_layout(pad=0.1)
    return fig


def save_figure(fig, path: str) -> None:
    """Save atomically as PNG and close the figure."""
    from .io.atomic import atomic_write

    plt = _pyplot()
    try:
        atomic_write(path, lambda f: fig.savefig(f, format="png"), binary=True)
    finally:
        plt.close(fig)
