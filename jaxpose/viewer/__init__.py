"""``jaxpose view``: a fit, or a sequence of fits, in 3D in the browser.

:mod:`jaxpose.viewer.scene` turns result files into what is drawn (plain NumPy,
testable without a browser); :mod:`jaxpose.viewer.app` draws it with viser, the
optional extra ``view`` (``pip install 'jaxpose[view]'``).  docs/viewer.md.
"""

from .scene import Frame, Link, View, load_view, node_names

__all__ = ["Frame", "Link", "View", "load_view", "node_names"]
