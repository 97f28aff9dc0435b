"""Detections read from a MOTChallenge det file (public detections), with a score threshold.

maggio2007 §4 runs PHD-MT on the output of external detectors; MOTChallenge sequences ship such
detections as ``det/det.txt`` (``frame,-1,x,y,w,h,score,...``).  This detector replays them: the
rows of the frame's index whose score is at least ``min_score``.  A frame past the end of the
file has no detections (empty :class:`~trackers.types.Detections`), not an error.
"""

from __future__ import annotations

import math
import os

from ..data.motio import MotTable, read_mot
from ..errors import InputError
from ..types import Detections, Frame


class FileDetector:
    """Replays the rows of ``table`` for each frame's index, keeping ``score >= min_score``."""

    name = "file"

    def __init__(self, table: MotTable, min_score: float = -math.inf):
        if not isinstance(table, MotTable):
            raise InputError(f"file detector: expected a MotTable of detections, "
                             f"got {type(table).__name__}")
        try:
            min_score = float(min_score)
        except (TypeError, ValueError):
            raise InputError(f"file detector: min_score must be a number, got {min_score!r}") from None
        if math.isnan(min_score):
            raise InputError("file detector: min_score must be a number, got nan")
        self.table = table
        self.min_score = min_score

    @classmethod
    def from_path(cls, path: str | os.PathLike, min_score: float = -math.inf) -> "FileDetector":
        """Read a det file (:func:`~trackers.data.motio.read_mot` raises InputError if it is
        missing or malformed)."""
        return cls(read_mot(path, "det"), min_score)

    def __call__(self, frame: Frame) -> Detections:
        index = getattr(frame, "index", frame)
        try:
            index = int(index)
        except (TypeError, ValueError):
            raise InputError(f"file detector: frame index must be an integer, got {index!r}") from None
        return self.table.detections(index, self.min_score)

    def __repr__(self) -> str:
        src = self.table.path or "<table>"
        return f"FileDetector({src!r}, min_score={self.min_score:g}, rows={len(self.table)})"
