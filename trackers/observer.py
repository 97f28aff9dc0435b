"""The Observer protocol: how trackers show their stages without knowing about Rerun.

Trackers call a small, viewer-neutral vocabulary with a *path* naming the stage
(``phd/particles/predicted``, ``phd/mass``, ``phd/clusters``, ``assoc/edges`` ...) and ask
:meth:`Observer.wants` before building a costly payload.  ``viewer_app.recorder`` maps these
calls onto Rerun entities and timelines; :class:`NullObserver` drops everything for free.

Levels, from least to most data: ``tracks`` < ``clusters`` < ``particles``.
``wants("clusters")`` is true when the recording level is ``clusters`` or ``particles``.

Coordinates are image pixels. ``boxes`` take ``(x, y, w, h)`` top-left, like everything else.
``stage(name)`` announces the stage inside the current frame (predict, birth, update,
resample, cluster, associate ...); payloads that follow belong to it.
"""

from __future__ import annotations

from typing import Optional, Protocol, Sequence

import numpy as np

LEVELS = ("tracks", "clusters", "particles")

#: Stages of one frame, in order; recorders map them onto a `stage` timeline.
STAGES = ("input", "predict", "birth", "update", "resample", "cluster", "associate", "output")


def level_rank(level: str) -> int:
    try:
        return LEVELS.index(level)
    except ValueError:
        raise ValueError(f"unknown level {level!r}; choose one of {', '.join(LEVELS)}") from None


class Observer(Protocol):
    def wants(self, level: str) -> bool: ...

    def stage(self, name: str) -> None: ...

    def points(self, path: str, xy: np.ndarray, *, weights: Optional[np.ndarray] = None,
               class_ids: Optional[np.ndarray] = None, labels: Optional[Sequence[str]] = None,
               radii: Optional[np.ndarray | float] = None) -> None: ...

    def boxes(self, path: str, boxes: np.ndarray, *, ids: Optional[np.ndarray] = None,
              labels: Optional[Sequence[str]] = None, class_ids: Optional[np.ndarray] = None) -> None: ...

    def segments(self, path: str, a: np.ndarray, b: np.ndarray, *,
                 class_ids: Optional[np.ndarray] = None, labels: Optional[Sequence[str]] = None,
                 radii: Optional[np.ndarray | float] = None) -> None: ...

    def strips(self, path: str, strips: Sequence[np.ndarray], *,
               ids: Optional[np.ndarray] = None) -> None: ...

    def scalar(self, path: str, value: float) -> None: ...

    def text(self, path: str, message: str, level: str = "INFO") -> None: ...

    def image(self, path: str, image_bgr: np.ndarray) -> None: ...


class NullObserver:
    """Records nothing and costs nothing: ``wants`` is always False."""

    def wants(self, level: str) -> bool:
        return False

    def stage(self, name: str) -> None:
        pass

    def points(self, path, xy, **kw) -> None:
        pass

    def boxes(self, path, boxes, **kw) -> None:
        pass

    def segments(self, path, a, b, **kw) -> None:
        pass

    def strips(self, path, strips, **kw) -> None:
        pass

    def scalar(self, path, value) -> None:
        pass

    def text(self, path, message, level="INFO") -> None:
        pass

    def image(self, path, image_bgr) -> None:
        pass


class ListObserver(NullObserver):
    """Keeps every call in memory (tests and debugging): ``calls`` is a list of
    ``(stage, kind, path, payload)`` tuples."""

    def __init__(self, level: str = "particles"):
        self._rank = level_rank(level)
        self.current_stage = "input"
        self.calls: list[tuple] = []

    def wants(self, level: str) -> bool:
        return level_rank(level) <= self._rank

    def stage(self, name: str) -> None:
        self.current_stage = name

    def _add(self, kind, path, payload):
        self.calls.append((self.current_stage, kind, path, payload))

    def points(self, path, xy, **kw):
        self._add("points", path, dict(xy=np.asarray(xy), **kw))

    def boxes(self, path, boxes, **kw):
        self._add("boxes", path, dict(boxes=np.asarray(boxes), **kw))

    def segments(self, path, a, b, **kw):
        self._add("segments", path, dict(a=np.asarray(a), b=np.asarray(b), **kw))

    def strips(self, path, strips, **kw):
        self._add("strips", path, dict(strips=list(strips), **kw))

    def scalar(self, path, value):
        self._add("scalar", path, float(value))

    def text(self, path, message, level="INFO"):
        self._add("text", path, message)

    def image(self, path, image_bgr):
        self._add("image", path, image_bgr.shape)

    def find(self, kind: str, path: str) -> list:
        return [c[3] for c in self.calls if c[1] == kind and c[2] == path]
