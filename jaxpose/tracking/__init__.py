"""Tracking: fit a depth stream frame after frame, each warm-started from the last.

``config`` (:class:`TrackConfig`), ``local`` (the search around the motion model's
prediction), ``step`` (one frame, :func:`track` over a sequence, :class:`Tracker`).
A pure functional core: no files, no terminal (``jaxpose track`` is the edge).
See docs/tracking.md.
"""

from .config import TrackConfig
from .local import local_fit
from .step import (GLOBAL, LOST, MODES, TRACKED, TrackFrame, Tracker, TrackState, initial_state, track, track_batched,
                   track_batched_from, track_step)

__all__ = ["GLOBAL", "LOST", "MODES", "TRACKED", "TrackConfig", "TrackFrame", "TrackState", "Tracker",
           "initial_state", "local_fit", "track", "track_batched", "track_batched_from",
           "track_step"]
