"""What a tracker shows of a frame: typed stage data, read by reporters (pull, not push).

A tracker's :meth:`~pfscope.trackers.api.Tracker.step` returns, besides its tracks, the
*stages* of the frame in the order of the tracker's own stage list (``predict, birth, update
...`` for PHD-MT; ``motion, parents, classify, children`` for a DLPF).  Each :class:`Stage`
holds *items* from a small, viewer-neutral vocabulary that says what things **mean**, never
how they look:

=============  ======================================================================
item           meaning
=============  ======================================================================
:class:`Points`    a cloud: particles (``weights``), members of something (``ids`` with
                   ``id_kind`` "track"/"cluster"/"detection"), per-point ``values``
                   (a classifier score, a scale ...): labelled per-track clouds are
                   Points with ``id_kind="track"``
:class:`Boxes`     boxes ``(x, y, w, h)`` with ids and named per-box ``values``
:class:`Segments`  edges a→b (association graph), ids and values
:class:`Mask`      an (H, W) class map (foreground mask ...) with class names
:class:`Field`     a dense (H, W) scalar field (motion magnitude, a score map ...)
:class:`Scalar`    one number per frame (PHD mass, particle count ...)
:class:`Event`     a text event (track confirmed, ended ...) with a severity
=============  ======================================================================

``role`` names what an item is for the app's styling (``"detection"``, ``"dropped"``,
``"candidate"`` ...); the engine never chooses colours, label strings or layout.

Why pull: the stage data is data the tracker computed anyway (arrays it already holds), so a
result is cheap to return and any consumer — the Rerun reporters of ``viewer_app``, a test, a
notebook — reads the same typed object after the step.  The contract is checkable in one
place: :class:`StageLog` refuses a stage the tracker did not declare, stages out of order and
items whose shapes disagree; a reporter needs to know only this module.

Levels (``tracks`` < ``clusters`` < ``particles``) gate what a tracker *builds*: it asks
:meth:`StageLog.wants` before building a costly item, and with ``level=None`` (the unrecorded
pipeline) only scalars and events are kept.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Optional, Sequence, Union

import numpy as np

LEVELS = ("tracks", "clusters", "particles")

#: What ``ids`` of an item mean; "track" ids share one colour per id everywhere in the app.
ID_KINDS = ("track", "cluster", "detection", "class")
SEVERITIES = ("DEBUG", "INFO", "WARN", "ERROR")


_RANK = {name: i for i, name in enumerate(LEVELS)}


def level_rank(level: str) -> int:
    r = _RANK.get(level) if isinstance(level, str) else None
    if r is None:
        raise ValueError(f"unknown level {level!r}; choose one of {', '.join(LEVELS)}")
    return r


def _arr(x, dtype, shape_tail: tuple, what: str) -> np.ndarray:
    a = np.asarray(x, dtype=dtype)
    if a.size == 0:
        return np.zeros((0,) + shape_tail, dtype=dtype)
    if a.ndim != 1 + len(shape_tail) or tuple(a.shape[1:]) != shape_tail:
        raise ValueError(f"{what}: expected shape (N, {', '.join(map(str, shape_tail))}), "
                         f"got {a.shape}" if shape_tail else f"{what}: expected (N,), got {a.shape}")
    return a


def _per_item(x, n: int, dtype, what: str) -> Optional[np.ndarray]:
    if x is None:
        return None
    a = np.asarray(x, dtype=dtype).reshape(-1)
    if len(a) != n:
        raise ValueError(f"{what}: {len(a)} values for {n} items")
    return a


def _values(values: Optional[Mapping[str, object]], n: int, what: str) -> dict:
    return {str(k): _per_item(v, n, np.float64, f"{what}.values[{k!r}]")
            for k, v in (values or {}).items()}


def _check_ids(ids, id_kind, n, what):
    ids = _per_item(ids, n, np.int64, f"{what}.ids")
    if id_kind is not None and id_kind not in ID_KINDS:
        raise ValueError(f"{what}.id_kind must be one of {', '.join(ID_KINDS)}, got {id_kind!r}")
    if ids is not None and id_kind is None:
        raise ValueError(f"{what}: ids need an id_kind ({', '.join(ID_KINDS)})")
    return ids


@dataclass(frozen=True)
class Points:
    """A point cloud in image pixels. ``xy`` (N, 2); ``weights`` (N,) non-negative (particle
    weights: the app maps them to a colormap); ``ids`` (N,) with ``id_kind``; ``values``: name →
    (N,) per-point scalars."""

    path: str
    xy: np.ndarray
    weights: Optional[np.ndarray] = None
    ids: Optional[np.ndarray] = None
    id_kind: Optional[str] = None
    values: Mapping[str, np.ndarray] = field(default_factory=dict)
    role: Optional[str] = None

    def __post_init__(self):
        xy = _arr(self.xy, np.float64, (2,), f"Points {self.path}")
        n = len(xy)
        object.__setattr__(self, "xy", xy)
        object.__setattr__(self, "weights", _per_item(self.weights, n, np.float64,
                                                      f"Points {self.path}.weights"))
        object.__setattr__(self, "ids", _check_ids(self.ids, self.id_kind, n, f"Points {self.path}"))
        object.__setattr__(self, "values", _values(self.values, n, f"Points {self.path}"))

    def __len__(self) -> int:
        return len(self.xy)


@dataclass(frozen=True)
class Boxes:
    """Boxes ``(x, y, w, h)`` top-left, pixels, (N, 4); ``ids`` with ``id_kind``; ``values``:
    name → (N,) per-box numbers (the app decides whether and how to label with them)."""

    path: str
    boxes: np.ndarray
    ids: Optional[np.ndarray] = None
    id_kind: Optional[str] = None
    values: Mapping[str, np.ndarray] = field(default_factory=dict)
    role: Optional[str] = None

    def __post_init__(self):
        b = _arr(self.boxes, np.float64, (4,), f"Boxes {self.path}")
        n = len(b)
        object.__setattr__(self, "boxes", b)
        object.__setattr__(self, "ids", _check_ids(self.ids, self.id_kind, n, f"Boxes {self.path}"))
        object.__setattr__(self, "values", _values(self.values, n, f"Boxes {self.path}"))

    def __len__(self) -> int:
        return len(self.boxes)


@dataclass(frozen=True)
class Segments:
    """Line segments ``a[i] → b[i]`` (N, 2) each; ids and values as for :class:`Boxes`."""

    path: str
    a: np.ndarray
    b: np.ndarray
    ids: Optional[np.ndarray] = None
    id_kind: Optional[str] = None
    values: Mapping[str, np.ndarray] = field(default_factory=dict)
    role: Optional[str] = None

    def __post_init__(self):
        a = _arr(self.a, np.float64, (2,), f"Segments {self.path}.a")
        b = _arr(self.b, np.float64, (2,), f"Segments {self.path}.b")
        if len(a) != len(b):
            raise ValueError(f"Segments {self.path}: {len(a)} starts but {len(b)} ends")
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "ids", _check_ids(self.ids, self.id_kind, len(a),
                                                   f"Segments {self.path}"))
        object.__setattr__(self, "values", _values(self.values, len(a), f"Segments {self.path}"))

    def __len__(self) -> int:
        return len(self.a)


@dataclass(frozen=True)
class Mask:
    """A class map over the image: ``mask`` (H, W) integer class index into ``classes`` (class
    0 is background), e.g. ``("background", "foreground", "shadow")``."""

    path: str
    mask: np.ndarray
    classes: Sequence[str] = ("background", "foreground")
    role: Optional[str] = None

    def __post_init__(self):
        m = np.asarray(self.mask)
        if m.ndim != 2 or not np.issubdtype(m.dtype, np.integer) and m.dtype != bool:
            raise ValueError(f"Mask {self.path}: expected an (H, W) integer array, got "
                             f"{m.shape} {m.dtype}")
        object.__setattr__(self, "mask", m.astype(np.uint8) if m.dtype == bool else m)
        object.__setattr__(self, "classes", tuple(self.classes))
        if m.size and int(m.max()) >= len(self.classes):
            raise ValueError(f"Mask {self.path}: class {int(m.max())} has no name in "
                             f"{self.classes}")


@dataclass(frozen=True)
class Field:
    """A dense scalar field over the image (or a coarser grid spanning it): ``values`` (H, W)
    float, ``unit`` for the colour scale (``"px/frame"``, ``"score"`` ...), ``vmin``/``vmax``
    the meaningful range when known."""

    path: str
    values: np.ndarray
    unit: str = ""
    vmin: Optional[float] = None
    vmax: Optional[float] = None
    role: Optional[str] = None

    def __post_init__(self):
        v = np.asarray(self.values, dtype=np.float32)
        if v.ndim != 2:
            raise ValueError(f"Field {self.path}: expected (H, W), got {v.shape}")
        object.__setattr__(self, "values", v)


@dataclass(frozen=True)
class Scalar:
    """One number for this frame (a time series)."""

    path: str
    value: float

    def __post_init__(self):
        object.__setattr__(self, "value", float(self.value))


@dataclass(frozen=True)
class Event:
    """A text event of this frame (``severity`` one of DEBUG/INFO/WARN/ERROR)."""

    path: str
    message: str
    severity: str = "INFO"

    def __post_init__(self):
        if self.severity not in SEVERITIES:
            raise ValueError(f"Event {self.path}: severity {self.severity!r} not in {SEVERITIES}")


Item = Union[Points, Boxes, Segments, Mask, Field, Scalar, Event]
ITEM_TYPES = (Points, Boxes, Segments, Mask, Field, Scalar, Event)


@dataclass(frozen=True)
class Stage:
    """One stage of one frame: its name (from the tracker's stage list) and its items."""

    name: str
    items: tuple[Item, ...] = ()

    def find(self, path: str) -> list[Item]:
        return [i for i in self.items if i.path == path]


#: declared stage list -> {stage name: place in it} (StageLog.stage's check, built once a list)
_WHERE: dict[tuple, dict] = {}


def _made(cls, **fields):
    """An instance of the frozen dataclass ``cls`` with ``fields`` set as its ``__init__``
    would set them (every field given, already in its final form: :class:`Scalar`'s value a
    float, :class:`Stage`'s items a tuple), without the generated ``__init__``'s
    per-field ``object.__setattr__`` calls -- a log makes ~7 scalars and ~6 stages every frame
    of every tracker, most of them at level None where nothing else is built."""
    item = object.__new__(cls)
    item.__dict__.update(fields)
    return item


class StageLog:
    """Builds a frame's :class:`Stage` tuple while a tracker steps, and checks the contract:
    stages must come from ``stages`` (the tracker's declared list) in increasing order, items
    must be vocabulary items.  ``level`` is the recording level (``None``: nothing but scalars
    and events is wanted).

    The log records the frame flat (stage names, ``(path, value)`` scalars and items, in
    call order) and makes the :class:`Stage` and :class:`Scalar` objects of it in
    :meth:`result`; at ``level=None`` not even then: :meth:`result` hands back a
    :class:`PendingStages` that makes them when first read (a run's pipeline reads no stage
    data of an unrecorded frame, and making ~6 stages and ~7 scalars a frame touched ~10 us
    of code and objects when the step's caches are cold).  Every check is made in the call
    (a wrong stage, an item that is not one, raises there)."""

    __slots__ = ("declared", "_rank", "_flat", "_name", "_pos", "_where")

    def __init__(self, stages: Sequence[str], level: Optional[str] = None):
        self.declared = stages if type(stages) is tuple else tuple(stages)
        self._rank = -1 if level is None else level_rank(level)
        self._flat: list = []
        self._name: Optional[str] = None
        self._pos = -1
        # stage name -> its place in the declared list (a tracker declares one tuple and
        # makes a log every frame: the map is built once per list)
        where = _WHERE.get(self.declared)
        if where is None:
            where = _WHERE[self.declared] = {n: i for i, n in reversed(list(enumerate(
                self.declared)))}
        self._where = where

    @property
    def recorded(self) -> bool:
        """False at ``level=None``: nothing but scalars and events is wanted (``wants`` is
        False for every level)."""
        return self._rank >= 0

    def wants(self, level: str) -> bool:
        """Should an item of ``level`` be built?"""
        r = _RANK.get(level) if type(level) is str else None
        return (level_rank(level) if r is None else r) <= self._rank

    def stage(self, name: str) -> None:
        """Start stage ``name``; items added next belong to it."""
        pos = self._where.get(name)
        if pos is None:
            raise ValueError(f"stage {name!r} is not in the tracker's stage list "
                             f"{self.declared}")
        if pos <= self._pos:
            raise ValueError(f"stage {name!r} after {self.declared[self._pos]!r}: stages must "
                             f"follow the declared order {self.declared}")
        self._flat.append(name)
        self._name, self._pos = name, pos

    def add(self, item: Item) -> None:
        if self._name is None:
            raise ValueError("StageLog.add before any stage()")
        if not isinstance(item, ITEM_TYPES):
            raise TypeError(f"not a report item: {type(item).__name__}")
        self._flat.append(item)

    def scalar(self, path: str, value: float) -> None:
        if self._name is None:
            raise ValueError("StageLog.add before any stage()")
        self._flat.append((path, float(value)))

    def event(self, path: str, message: str, severity: str = "INFO") -> None:
        self.add(Event(path, message, severity))

    def result(self) -> "tuple[Stage, ...] | PendingStages":
        """The frame's stages (call once, after the step): a tuple, or at ``level=None`` a
        :class:`PendingStages` of them (:class:`~pfscope.trackers.api.StepResult` takes
        either; its ``stages`` is always the tuple)."""
        flat, self._flat = self._flat, []
        self._name = None
        if self._rank < 0:
            return PendingStages(flat)
        return _stages_of(flat)


def _stages_of(flat: list) -> "tuple[Stage, ...]":
    """The :class:`Stage` tuple of a :class:`StageLog`'s flat record: a ``str`` starts a stage,
    a tuple is a scalar's ``(path, value)``, anything else an item."""
    stages: list = []
    name: Optional[str] = None
    items: list = []
    for x in flat:
        if type(x) is str:
            if name is not None:
                stages.append(_made(Stage, name=name, items=tuple(items)))
            name, items = x, []
        elif type(x) is tuple:
            items.append(_made(Scalar, path=x[0], value=x[1]))
        else:
            items.append(x)
    if name is not None:
        stages.append(_made(Stage, name=name, items=tuple(items)))
    return tuple(stages)


class PendingStages:
    """A level-None :class:`StageLog`'s frame, made into its :class:`Stage` tuple on first
    use (:meth:`stages`; also a read-only sequence of them).  The record holds floats and
    immutable items only, so the stages are those the step would have made."""

    __slots__ = ("_flat", "_stages")

    def __init__(self, flat: list):
        self._flat = flat
        self._stages: Optional[tuple] = None

    def stages(self) -> "tuple[Stage, ...]":
        st = self._stages
        if st is None:
            st = self._stages = _stages_of(self._flat)
            self._flat = []
        return st

    def __len__(self) -> int:
        return len(self.stages())

    def __iter__(self):
        return iter(self.stages())

    def __getitem__(self, i):
        return self.stages()[i]

    def __eq__(self, other) -> bool:
        if isinstance(other, PendingStages):
            other = other.stages()
        return self.stages() == other

    def __hash__(self) -> int:
        return hash(self.stages())

    def __repr__(self) -> str:
        return repr(self.stages())


def find(stages: Sequence[Stage], path: str, kind: Optional[type] = None) -> list:
    """Every item at ``path`` (of type ``kind``) across ``stages``."""
    return [i for s in stages for i in s.items
            if i.path == path and (kind is None or isinstance(i, kind))]


__all__ = ["LEVELS", "ID_KINDS", "level_rank", "Points", "Boxes", "Segments", "Mask", "Field",
           "Scalar", "Event", "Item", "ITEM_TYPES", "Stage", "StageLog", "PendingStages", "find"]
