"""The smallest tracker: every detection is a one-frame track.  For wiring, for looking at a
detector's raw output, and as the worked example of "Adding a tracker" in the README."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .api import Rows, StepResult, register
from .params import param, to_dict
from .report import StageLog
from .types import Detections, Frame, TrackSet


@dataclass(frozen=True)
class PassThroughParams:
    min_score: float = param(float("-inf"), "drop detections scoring below this")


@register
class PassThroughTracker:
    """Reports every detection as a one-frame track (ids 1..N per frame); no tracking."""

    name = "passthrough"
    paper = "-"
    stages = ("select",)
    needs_detections = True
    needs_image = False
    Params = PassThroughParams

    def __init__(self, params: Optional[PassThroughParams] = None, *,
                 rng: Optional[np.random.Generator] = None):
        self.params = params or PassThroughParams()

    def step(self, frame: Frame, detections: Optional[Detections],
             level: Optional[str] = None) -> StepResult:
        log = StageLog(self.stages, level)
        log.stage("select")
        dets = detections if detections is not None else Detections.empty()
        kept = dets.select(dets.scores >= self.params.min_score)
        log.scalar("passthrough/dropped", len(dets) - len(kept))
        tracks = TrackSet(np.arange(1, len(kept) + 1), kept.boxes)
        return StepResult(tracks, [(frame.index, tracks)], log.result())

    def finish(self) -> Rows:
        return []

    def config(self) -> dict:
        return {"tracker": self.name, "params": to_dict(self.params)}
