"""The failure index of a run with ground truth: ID switches, false tracks, lost tracks, long
misses and the worst frames by OSPA, found from the per-frame metrics
(:class:`~pfscope.trackers.eval.online.FrameMetrics`) as the run goes.

Definitions (each threshold is a parameter of :class:`EventIndex`):

- **id_switch**: a CLEAR-MOT identity switch (``FrameMetrics.switch_idx``): true target ``g``
  is now matched to track ``b`` after having last been matched to track ``a``.
- A track *ends* when it has been absent for more than ``track_gap`` frames (trackers that
  show a track only when its estimate is confident skip frames; those gaps are not ends).
- **false_track**: a track that was shown in ``min_track_life`` frames or more and was matched
  to a true target in less than ``false_fraction`` of them; reported at its first frame once it
  ends, or at the end of the run.
- **lost_track**: a track that ends while the true target it was matched to in its last frame
  is still present (and scored); reported at the track's last frame.
- **long_miss**: a true target unmatched for ``long_miss`` consecutive frames or more while
  present; reported at the first frame of the streak once it ends or at the end of the run.

Memory is bounded by the live tracks and the true targets seen (one small entry each), and the
``worst`` highest-OSPA frames (a heap).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..types import GroundTruth, TrackSet

KINDS = ("id_switch", "false_track", "lost_track", "long_miss")


@dataclass(frozen=True)
class TrackEvent:
    """One entry of the failure index. ``frame`` is where to look first (a switch's frame, a
    false track's or a miss streak's first frame); ``last_frame`` where it ends."""

    kind: str
    frame: int
    last_frame: int
    track_ids: tuple[int, ...] = ()
    gt_ids: tuple[int, ...] = ()
    detail: str = ""

    @property
    def message(self) -> str:
        t = ", ".join(str(i) for i in self.track_ids)
        g = ", ".join(str(i) for i in self.gt_ids)
        if self.kind == "id_switch":
            return (f"ID switch at frame {self.frame}: gt {g} moved from track "
                    f"{self.track_ids[0]} to track {self.track_ids[-1]}")
        if self.kind == "false_track":
            return (f"false track {t}: frames {self.frame}-{self.last_frame}, {self.detail}")
        if self.kind == "lost_track":
            return (f"lost track {t} at frame {self.frame}: last seen there while gt {g} "
                    f"stayed visible")
        return (f"long miss: gt {g} unmatched for frames {self.frame}-{self.last_frame} "
                f"({self.last_frame - self.frame + 1} frames)")

    @property
    def severity(self) -> str:
        """WARN for what breaks an identity (switches, lost tracks), INFO for the rest."""
        return "WARN" if self.kind in ("id_switch", "lost_track") else "INFO"

    @property
    def short(self) -> str:
        """The body of the viewer's row: the kind and its frames; the ids are in their own
        columns (``track_ids``, ``gt_ids``)."""
        name = self.kind.replace("_", " ")
        if self.last_frame != self.frame:
            return f"{name}, frames {self.frame}-{self.last_frame}"
        return f"{name}, frame {self.frame}"

    def to_dict(self) -> dict:
        return {"kind": self.kind, "frame": self.frame, "last_frame": self.last_frame,
                "track_ids": list(self.track_ids), "gt_ids": list(self.gt_ids),
                "severity": self.severity, "message": self.message}


@dataclass
class _Track:
    first: int
    last: int
    alive: int = 0
    matched: int = 0
    last_gt: Optional[int] = None   # gt matched in its last frame


class EventIndex:
    """Feed :meth:`update` every frame (in order), then :meth:`finish`; both return the events
    that became final.  :meth:`worst_frames` gives the highest-OSPA frames."""

    def __init__(self, *, long_miss: int = 10, min_track_life: int = 5,
                 false_fraction: float = 0.5, worst: int = 10, track_gap: int = 5):
        if long_miss < 1 or min_track_life < 1 or not 0 < false_fraction <= 1 or worst < 0 \
                or track_gap < 0:
            raise ValueError("EventIndex: long_miss, min_track_life >= 1, "
                             "0 < false_fraction <= 1, worst >= 0, track_gap >= 0")
        self.track_gap = int(track_gap)
        self.long_miss, self.min_track_life = int(long_miss), int(min_track_life)
        self.false_fraction, self.worst = float(false_fraction), int(worst)
        self._tracks: dict[int, _Track] = {}
        self._last_track_of_gt: dict[int, int] = {}
        self._miss: dict[int, tuple[int, int]] = {}   # gt id -> (first, last) unmatched frame
        self._heap: list[tuple[float, int]] = []
        self._last_frame = 0
        #: the first frame the tracker showed a track: frames before it are its start-up
        #: (no tracker confirms a track before it has seen enough frames), whose OSPA is the
        #: cut-off by construction; they are left out of the worst frames
        self.first_shown: Optional[int] = None
        self.counts = {k: 0 for k in KINDS}

    @property
    def last_frame(self) -> int:
        """The last frame fed to :meth:`update` (0 before the first)."""
        return self._last_frame

    def _count(self, events: list[TrackEvent]) -> list[TrackEvent]:
        for e in events:
            self.counts[e.kind] += 1
        return events

    def update(self, frame: int, gt: GroundTruth, tracks: TrackSet, m) -> list[TrackEvent]:
        frame = int(frame)
        self._last_frame = frame
        out: list[TrackEvent] = []
        t_ids = tracks.ids.astype(np.int64)
        g_ids = gt.ids.astype(np.int64)
        pairs = {int(t_ids[ti]): int(g_ids[gi])
                 for gi, ti in zip(m.match_gt_idx.tolist(), m.match_track_idx.tolist())}
        # identity switches: the matched gt's previous track
        for ti in m.switch_idx.tolist():
            tid = int(t_ids[ti])
            g = pairs.get(tid)
            if g is None:
                continue
            before = self._last_track_of_gt.get(g, -1)
            out.append(TrackEvent("id_switch", frame, frame, (before, tid), (g,)))
        for tid, g in pairs.items():
            self._last_track_of_gt[g] = tid
        # tracks that ended (absent from this frame)
        scored_gt = set(np.delete(g_ids, m.ignored_gt_idx).tolist()) if len(g_ids) else set()
        present = set(t_ids.tolist())
        for tid in [t for t, st in self._tracks.items()
                    if t not in present and frame - st.last > self.track_gap]:
            out.extend(self._end_track(tid, self._tracks.pop(tid), scored_gt))
        for tid in present:
            st = self._tracks.get(tid)
            if st is None:
                st = self._tracks[tid] = _Track(frame, frame)
            st.last, st.alive = frame, st.alive + 1
            st.last_gt = pairs.get(tid)
            if st.last_gt is not None:
                st.matched += 1
        # miss streaks of scored true targets
        missed = set(g_ids[m.fn_idx].tolist()) if len(m.fn_idx) else set()
        for g in [g for g in self._miss if g not in missed]:
            out.extend(self._end_miss(g, self._miss.pop(g)))
        for g in missed:
            first, _ = self._miss.get(g, (frame, frame))
            self._miss[g] = (first, frame)
        # worst frames by OSPA (ties: the earlier frame is kept), after the start-up
        if self.first_shown is None and len(t_ids):
            self.first_shown = frame
        if self.worst and self.first_shown is not None:
            # ties (OSPA saturates at its cut-off): the frame with more errors, then the earlier
            item = (float(m.ospa), int(m.fp + m.fn + m.idsw), -frame)
            if len(self._heap) < self.worst:
                heapq.heappush(self._heap, item)
            elif item > self._heap[0]:
                heapq.heapreplace(self._heap, item)
        return self._count(sorted(out, key=lambda e: (e.frame, e.kind)))

    def _end_track(self, tid: int, st: _Track, scored_gt: set) -> list[TrackEvent]:
        out = []
        if st.alive >= self.min_track_life and st.matched < self.false_fraction * st.alive:
            out.append(TrackEvent("false_track", st.first, st.last, (tid,), (),
                                  f"matched a true target in {st.matched} of {st.alive} frames"))
        if st.last_gt is not None and st.last_gt in scored_gt:
            out.append(TrackEvent("lost_track", st.last, st.last, (tid,), (st.last_gt,)))
        return out

    def _end_miss(self, g: int, streak: tuple[int, int]) -> list[TrackEvent]:
        first, last = streak
        if last - first + 1 >= self.long_miss:
            return [TrackEvent("long_miss", first, last, (), (g,))]
        return []

    def finish(self) -> list[TrackEvent]:
        """Events still open at the end of the run (tracks alive, misses ongoing)."""
        out: list[TrackEvent] = []
        for tid, st in sorted(self._tracks.items()):
            if st.alive >= self.min_track_life and st.matched < self.false_fraction * st.alive:
                out.append(TrackEvent("false_track", st.first, st.last, (tid,), (),
                                      f"matched a true target in {st.matched} of {st.alive} "
                                      f"frames"))
        for g, streak in sorted(self._miss.items()):
            out.extend(self._end_miss(g, streak))
        self._tracks, self._miss = {}, {}
        return self._count(sorted(out, key=lambda e: (e.frame, e.kind)))

    def worst_frames(self) -> list[tuple[int, float]]:
        """``(frame, ospa)`` of the worst frames, worst first."""
        return [(-f, v) for v, _, f in sorted(self._heap, reverse=True)]


__all__ = ["EventIndex", "TrackEvent", "KINDS"]
