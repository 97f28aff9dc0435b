"""Readers and writers for MOTChallenge text files (gt, det, tracks), validating every line.

Formats (comma separated, frames 1-based, boxes top-left x, y, width, height in pixels):

- gt:     ``frame,id,x,y,w,h,conf,class,vis``   (``conf=0``: box to ignore, MOT15 "ambiguous")
- det:    ``frame,-1,x,y,w,h,score,-1,-1,-1``   (public detections; extra columns allowed)
- tracks: ``frame,id,x,y,w,h,-1,-1,-1,-1``      (tracker output, MOTChallenge submission)

A malformed line raises :class:`~trackers.errors.InputError` naming ``file:line``.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..outputs import incomplete_path
from ..types import Detections, GroundTruth, TrackSet

KINDS = ("gt", "det", "tracks")
_MIN_COLS = {"gt": 6, "det": 7, "tracks": 6}


@dataclass(frozen=True)
class MotTable:
    """All rows of one MOT file as columns. ``frame (N,) int64, id (N,) int64,
    boxes (N,4) float64, score (N,) float64`` (score is ``conf`` for gt), ``cls``, ``vis``."""

    frame: np.ndarray
    id: np.ndarray
    boxes: np.ndarray
    score: np.ndarray
    cls: np.ndarray
    vis: np.ndarray
    path: str = ""

    def __len__(self) -> int:
        return len(self.frame)

    @property
    def last_frame(self) -> int:
        return int(self.frame.max()) if len(self.frame) else 0

    def rows_at(self, frame: int) -> np.ndarray:
        """Indices of the rows of ``frame`` (uses the sort order built on first call)."""
        if not hasattr(self, "_index"):
            order = np.argsort(self.frame, kind="stable")
            object.__setattr__(self, "_index", (order, self.frame[order]))
        order, sorted_frames = self._index  # type: ignore[attr-defined]
        lo, hi = np.searchsorted(sorted_frames, [frame, frame + 1])
        return order[lo:hi]

    def detections(self, frame: int, min_score: float = -math.inf) -> Detections:
        r = self.rows_at(frame)
        r = r[self.score[r] >= min_score]
        return Detections(self.boxes[r], self.score[r])

    @property
    def has_classes(self) -> bool:
        """True for a gt in MOT16+ layout: every row has an integer class id in 1..13 (column 8)
        and a visibility in [0, 1] (column 9). A MOT15 gt has -1 or world coordinates there
        (or, converted, ``vis = -1``); an empty table has no classes."""
        if not hasattr(self, "_has_classes"):
            c, v = self.cls, self.vis
            ok = bool(len(c)) and bool(np.all((c == np.round(c)) & (c >= 1) & (c <= 13))
                                      and np.all((v >= 0) & (v <= 1)))
            object.__setattr__(self, "_has_classes", ok)
        return self._has_classes  # type: ignore[attr-defined]

    def ground_truth(self, frame: int) -> GroundTruth:
        """The gt boxes of ``frame``: ``ignore`` where conf = 0, and the class ids when the
        table :attr:`has_classes` (else ``cls`` is None)."""
        r = self.rows_at(frame)
        cls = self.cls[r].astype(np.int64) if self.has_classes else None
        return GroundTruth(self.id[r], self.boxes[r], self.score[r] == 0, cls)

    def tracks(self, frame: int) -> TrackSet:
        r = self.rows_at(frame)
        return TrackSet(self.id[r], self.boxes[r])


def table_from_tracksets(rows, path: str = "") -> MotTable:
    """A tracks :class:`MotTable` from ``(frame, TrackSet)`` pairs (in memory, no file)."""
    rows = [(f, ts) for f, ts in rows if len(ts)]
    n = sum(len(ts) for _, ts in rows)
    frame = np.concatenate([np.full(len(ts), f, dtype=np.int64) for f, ts in rows]) if n else \
        np.zeros(0, dtype=np.int64)
    ids = np.concatenate([ts.ids for _, ts in rows]) if n else np.zeros(0, dtype=np.int64)
    boxes = np.concatenate([ts.boxes for _, ts in rows]) if n else np.zeros((0, 4))
    return MotTable(frame=frame, id=ids, boxes=boxes, score=np.ones(n), cls=np.full(n, -1.0),
                    vis=np.full(n, -1.0), path=path)


def read_mot(path: str | os.PathLike, kind: str = "gt") -> MotTable:
    """Read and validate a MOT text file. Empty files give an empty table."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}")
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise InputError(f"{path}: no such {kind} file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read {kind} file ({e.__class__.__name__}: {e})") from None
    fast = _read_plain(text, kind, str(path))
    if fast is not None:
        return fast
    rows = []
    ints: list = []
    min_cols = _MIN_COLS[kind]
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = [p.strip() for p in s.replace(";", ",").split(",")]
        if len(parts) == 1:
            parts = s.split()
        where = f"{path}:{lineno}"
        if len(parts) < min_cols:
            raise InputError(f"{where}: expected at least {min_cols} comma-separated values "
                             f"for a {kind} line, got {len(parts)}: {s[:60]!r}")
        try:
            vals = [float(p) for p in parts[:10]]
        except ValueError:
            raise InputError(f"{where}: not a number in {s[:60]!r}") from None
        if not all(math.isfinite(v) for v in vals):
            raise InputError(f"{where}: NaN or infinite value in {s[:60]!r}")
        frame, tid, x, y, w, h = vals[:6]
        if frame != int(frame) or frame < 1:
            raise InputError(f"{where}: frame must be a positive integer, got {parts[0]!r}")
        if tid != int(tid):
            raise InputError(f"{where}: id must be an integer, got {parts[1]!r}")
        if kind in ("gt", "tracks") and tid < 0:
            raise InputError(f"{where}: {kind} id must be >= 0, got {parts[1]!r}")
        if w <= 0 or h <= 0:
            raise InputError(f"{where}: box width and height must be positive, got w={w:g} h={h:g}")
        score = vals[6] if len(vals) > 6 else 1.0
        cls = vals[7] if len(vals) > 7 else -1.0
        vis = vals[8] if len(vals) > 8 else -1.0
        # frame and id as integers from their text: a float loses ids >= 2**53
        frame_i, tid_i = _exact_int(parts[0], frame), _exact_int(parts[1], tid)
        if not (-2 ** 63 <= tid_i < 2 ** 63 and frame_i < 2 ** 63):
            raise InputError(f"{where}: id or frame out of the 64-bit range: {s[:60]!r}")
        ints.append((frame_i, tid_i))
        rows.append((frame, tid, x, y, w, h, score, cls, vis))
    arr = np.array(rows, dtype=np.float64).reshape(-1, 9)
    iarr = np.array(ints, dtype=np.int64).reshape(-1, 2)
    return MotTable(frame=iarr[:, 0].copy(), id=iarr[:, 1].copy(),
                    boxes=arr[:, 2:6].copy(), score=arr[:, 6].copy(), cls=arr[:, 7].copy(),
                    vis=arr[:, 8].copy(), path=str(path))


_PLAIN = re.compile(r"[0-9.eE+\-,\n]+")


def _read_plain(text: str, kind: str, path: str) -> "MotTable | None":
    """:func:`read_mot`'s table of a plain file in one vectorised pass: every line the same
    number (at least the kind's minimum) of comma-separated decimal numbers, nothing else (no
    blank or comment line, space, ``;`` or ``\\r``), every row valid, frames and ids below
    2**53 (their floats are then exact).  None for anything else: the line-by-line reader then
    reads it and names the first bad line.  The same numbers as that reader (correctly rounded
    parsing in both)."""
    body = text[:-1] if text.endswith("\n") else text
    if not body or _PLAIN.fullmatch(body) is None:
        return None
    lines = body.split("\n")
    commas = {line.count(",") for line in lines}
    if len(commas) != 1:
        return None
    ncols = commas.pop() + 1
    if ncols < _MIN_COLS[kind]:
        return None
    cells = np.array(body.replace("\n", ",").split(","), dtype=str).reshape(len(lines), ncols)
    try:
        vals = cells[:, :10].astype(np.float64)
    except ValueError:
        return None
    frame, tid, w, h = vals[:, 0], vals[:, 1], vals[:, 4], vals[:, 5]
    ok = (np.isfinite(vals).all() and (frame == np.floor(frame)).all() and (frame >= 1).all()
          and (tid == np.floor(tid)).all() and (np.abs(vals[:, :2]) < 2.0 ** 53).all()
          and (w > 0).all() and (h > 0).all()
          and (kind not in ("gt", "tracks") or (tid >= 0).all()))
    if not ok:
        return None
    n = len(vals)
    col = lambda j, fill: vals[:, j].copy() if ncols > j else np.full(n, fill)  # noqa: E731
    return MotTable(frame=frame.astype(np.int64), id=tid.astype(np.int64),
                    boxes=vals[:, 2:6].copy(), score=col(6, 1.0), cls=col(7, -1.0),
                    vis=col(8, -1.0), path=path)


def _exact_int(text: str, as_float: float) -> int:
    """``"12"`` → 12 exactly (any size); ``"12.0"`` → 12 (via the float)."""
    try:
        return int(text.strip())
    except ValueError:
        return int(as_float)


def format_rows(kind: str, frame, ids, boxes, score=None, cls=None, vis=None) -> list[str]:
    """Format rows of one kind as MOT text lines (no trailing newline)."""
    frame = np.asarray(frame, dtype=np.int64).reshape(-1)
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    n = len(frame)
    given = score is not None
    score = np.ones(n) if score is None else np.asarray(score, dtype=np.float64).reshape(-1)
    lines = []
    for i in range(n):
        x, y, w, h = boxes[i]
        head = f"{frame[i]},{ids[i]},{x:.3f},{y:.3f},{w:.3f},{h:.3f}"
        if kind == "gt":
            c = 1 if cls is None else int(cls[i])
            v = -1 if vis is None else float(vis[i])
            lines.append(f"{head},{int(score[i])},{c},{v:.3f}")
        elif kind == "det":
            lines.append(f"{head},{score[i]:.3f},-1,-1,-1")
        elif given:  # tracks with a confidence (PHD-MT: 1 = estimate, 0.5 = filled gap frame)
            lines.append(f"{head},{score[i]:g},-1,-1,-1")
        else:
            lines.append(f"{head},-1,-1,-1,-1")
    return lines


def write_mot(path: str | os.PathLike, kind: str, frame, ids, boxes, score=None, cls=None,
              vis=None) -> None:
    """Write a whole MOT file atomically (temp file + rename: never half-written)."""
    path = Path(path)
    lines = format_rows(kind, frame, ids, boxes, score, cls, vis)
    tmp = path.with_name(path.name + ".part")
    try:
        tmp.write_text("".join(line + "\n" for line in lines))
        os.replace(tmp, path)
    except OSError as e:
        raise InputError(f"{path}: cannot write ({e.strerror or e})") from None


class TrackWriter:
    """Appends a TrackSet per frame to ``path + '.part'`` and renames it on close, so a
    complete-looking tracks file only exists once the run finished (or was stopped cleanly)."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._tmp = self.path.with_name(self.path.name + ".part")
        try:
            self._fh = open(self._tmp, "w")
        except OSError as e:
            raise InputError(f"{self.path}: cannot write tracks ({e.strerror or e})") from None

    def write(self, frame: int, tracks: TrackSet) -> None:
        if len(tracks):
            lines = format_rows("tracks", np.full(len(tracks), frame), tracks.ids, tracks.boxes,
                                score=getattr(tracks, "conf", None))
            self._fh.write("".join(line + "\n" for line in lines))
            self._fh.flush()  # a killed run leaves the rows written so far in the .part file

    def close(self) -> None:
        """The run finished: the file takes its final name."""
        if not self._fh.closed:
            self._fh.close()
            os.replace(self._tmp, self.path)

    @property
    def incomplete_path(self) -> Path:
        return incomplete_path(self.path)

    def abort(self) -> Path:
        """The run failed or was interrupted: keep what was written as
        ``<name>.incomplete<suffix>``, never under the final name (a previous good file there is
        left untouched)."""
        if not self._fh.closed:
            self._fh.close()
        if self._tmp.exists():
            os.replace(self._tmp, self.incomplete_path)
        return self.incomplete_path

