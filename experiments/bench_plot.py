"""Log-log plot of the benchmark: time of one population evaluation against P·N·L.

``python experiments/bench_plot.py [experiments/results/bench.json] [-o bench_scaling.png]``
redraws the plot from a results file; ``bench.py`` calls :func:`plot_scaling` at the end
of a run.  Needs matplotlib (``pip install matplotlib``, or ``pip install -e '.[viz]'``);
without it the plot is skipped with a message.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

from outputs import log, pyplot, save_figure

METHODS = (("kernel", "jaxpose kernel", "C0"), ("naive_vmap", "naive jax.vmap", "C1"), ("numpy", "NumPy loop", "C2"))
MARKERS = {8: "o", 17: "s", 40: "^"}


def plot_scaling(results: dict, path: str) -> str | None:
    """Write the scaling plot of ``results`` (bench.json's content) to ``path``; None if impossible."""
    try:
        plt = pyplot()
    except ImportError:
        log("bench_plot: matplotlib is not installed, no scaling plot (pip install matplotlib)")
        return None
    recs = [r for r in results.get("configs", {}).values() if r.get("done")]
    if not recs:
        log("bench_plot: no finished configuration to plot")
        return None
    fig, (ax_t, ax_r) = plt.subplots(1, 2, figsize=(12, 6))
    for method, label, colour in METHODS:
        for L in sorted({r["L"] for r in recs}):
            rs = sorted((r for r in recs if r["L"] == L), key=lambda r: r["distances"])
            x = [r["distances"] for r in rs]
            t = [r["time_full_P_s"][method] for r in rs]
            rate = [r[method]["evals_per_s"] for r in rs]
            sub = [r[method].get("subset", False) for r in rs]
            mk = MARKERS.get(L, "D")
            name = f"{label}, L={L}"
            for ax, y in ((ax_t, t), (ax_r, rate)):
                if ax is ax_t:
                    ax.plot(x, y, color=colour, lw=0.6, alpha=0.5)
                xm = [a for a, s in zip(x, sub) if not s]
                ym = [b for b, s in zip(y, sub) if not s]
                xs = [a for a, s in zip(x, sub) if s]
                ys = [b for b, s in zip(y, sub) if s]
                ax.scatter(xm, ym, color=colour, marker=mk, s=22, label=name if ax is ax_t else None)
                ax.scatter(xs, ys, facecolors="none", edgecolors=colour, marker=mk, s=22,
                           label=(name + " (from P′ < P)") if (ax is ax_t and xs) else None)
    ax_t.set(xscale="log", yscale="log", xlabel="P·N·L (point-to-capsule distances per call)",
             ylabel="seconds per population evaluation", title="time (hollow: extrapolated from fewer individuals)")
    ax_r.set(xscale="log", yscale="log", xlabel="P·N·L", ylabel="distances per second", title="throughput")
    for ax in (ax_t, ax_r):
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = ax_t.get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=7, frameon=False)
    m = results.get("machine", {})
    fig.suptitle(f"jaxpose objective ({results.get('mode')}): {m.get('cpu')}, {m.get('cores_usable')} cores, "
                 f"jax {m.get('jax')} {m.get('backend')}; load avg {m.get('load_average_start')}", fontsize=9)
    fig.tight_layout(rect=(0, 0.14, 1, 1))
    save_figure(fig, path, dpi=120)
    return path


def main(argv=None) -> int:
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("json", nargs="?", default=os.path.join(here, "results", "bench.json"))
    ap.add_argument("-o", "--out", default=None, help="PNG path (default: bench_scaling.png beside the JSON)")
    args = ap.parse_args(argv)
    with open(args.json) as f:
        results = json.load(f)
    out = args.out or os.path.join(os.path.dirname(os.path.abspath(args.json)), "bench_scaling.png")
    path = plot_scaling(results, out)
    if path:
        print(path)
    return 0 if path else 1


if __name__ == "__main__":
    sys.exit(main())
