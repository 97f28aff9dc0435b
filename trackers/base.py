"""The tracker interface shared by every tracker, and the registry the CLI picks from.

A tracker is a thin stateful object: ``step(frame, detections, obs)`` runs one frame and
returns the frame's :class:`~trackers.types.TrackSet`; stages are reported to ``obs``.
"""

from __future__ import annotations

from typing import Callable, Protocol

import numpy as np

from .observer import NullObserver, Observer
from .types import Detections, Frame, TrackSet


class Tracker(Protocol):
    name: str

    def step(self, frame: Frame, detections: Detections, obs: Observer = ...) -> TrackSet: ...

    def config(self) -> dict: ...


class PassThroughTracker:
    """Reports every detection as a one-frame track (ids 1..N per frame). For wiring and for
    looking at a detector's raw output, not for tracking."""

    name = "passthrough"

    def __init__(self, rng: np.random.Generator | None = None):
        self.rng = rng

    def step(self, frame: Frame, detections: Detections, obs: Observer = NullObserver()) -> TrackSet:
        return TrackSet(np.arange(1, len(detections) + 1), detections.boxes)

    def config(self) -> dict:
        return {"tracker": self.name}


def _phd(rng, **kw):
    from .phd.tracker import PHDTracker

    return PHDTracker(rng=rng, **kw)


def _mt(rng, **kw):
    from .phd.tracker import MTTracker

    return MTTracker(rng=rng, **kw)


TRACKERS: dict[str, Callable[..., Tracker]] = {
    "phd": _phd,
    "mt": _mt,
    "passthrough": lambda rng, **kw: PassThroughTracker(rng),
}
DEFAULT_TRACKER = "phd"


def make_tracker(name: str, seed: int = 0, **options) -> Tracker:
    """Build tracker ``name`` with its own ``numpy.random.Generator`` seeded by ``seed``."""
    if name not in TRACKERS:
        raise ValueError(f"unknown tracker {name!r}; choose one of {', '.join(TRACKERS)}")
    return TRACKERS[name](np.random.default_rng(seed), **options)
