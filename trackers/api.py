"""The tracker API: the :class:`Tracker` protocol, :class:`StepResult` and the registry.

A tracker is a thin stateful class.  It declares

- ``name`` and ``paper`` (for ``pfscope trackers``),
- ``stages``: its own ordered stage list (the recorder's ``stage`` timeline follows it),
- ``needs_detections`` / ``needs_image``: what the pipeline must give it (a detector is built
  only when some tracker needs detections),
- ``Params``: a frozen dataclass of documented fields (:mod:`pfscope.trackers.params`), and
  ``presets`` of it (``paper``: the paper's settings, unchanged),

and implements ``step(frame, detections, level)`` → :class:`StepResult`, ``finish()`` (rows
still held back at the end of a sequence) and ``config()``.  ``@register`` next to the class
puts it in the registry; the CLI's choices, ``--set NAME=VALUE`` options and help come from
there.  See the README, "Adding a tracker".
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Any, Optional, Protocol, TypeVar, runtime_checkable

import numpy as np

from .errors import did_you_mean
from .params import describe, to_dict, with_options
from .report import PendingStages, Stage
from .types import Detections, Frame, TrackSet

#: Rows for the tracks file: ``(frame index, TrackSet)``, final (never revised).
Rows = list[tuple[int, TrackSet]]


@dataclass(frozen=True, init=False)
class StepResult:
    """What one :meth:`Tracker.step` returns.

    tracks: the targets the tracker reports *at this frame* (what a live view shows).
    rows: rows final for the tracks file, possibly of earlier frames (a tracker that confirms
        tracks with a bounded lag reports a track from its first frame once confirmed).
    stages: the frame's stage data, in the order of the tracker's ``stages``
        (:mod:`pfscope.trackers.report`).  Given a :class:`~.report.PendingStages` (what a
        level-None :class:`~.report.StageLog` returns), the tuple is made on first read.
    """

    tracks: TrackSet
    rows: Rows
    stages: tuple[Stage, ...]

    def __init__(self, tracks: TrackSet, rows: Optional[Rows] = None,
                 stages: "tuple[Stage, ...] | PendingStages" = ()):
        # (a frozen dataclass's generated __init__ sets each field by object.__setattr__:
        # the instance dict directly; made every frame of every lane)
        d = self.__dict__
        d["tracks"] = tracks
        d["rows"] = [] if rows is None else rows
        if type(stages) is PendingStages:
            d["_pending"] = stages
        else:
            d["stages"] = stages

    def __getattr__(self, name):
        # only for a missing instance attribute: ``stages`` when still pending
        if name == "stages":
            d = self.__dict__
            pending = d.get("_pending")
            if pending is not None:
                d["stages"] = st = pending.stages()
                return st
        raise AttributeError(name)


@runtime_checkable
class Tracker(Protocol):
    """The protocol every tracker implements (checked by mypy in the tests)."""

    # Declared as read-only members: class attributes (``stages = ("predict", ...)``) satisfy them.
    @property
    def name(self) -> str: ...

    @property
    def paper(self) -> str: ...

    @property
    def stages(self) -> tuple[str, ...]: ...

    @property
    def needs_detections(self) -> bool: ...

    @property
    def needs_image(self) -> bool: ...

    def step(self, frame: Frame, detections: Optional[Detections],
             level: Optional[str] = None) -> StepResult: ...

    def finish(self) -> Rows: ...

    def config(self) -> dict: ...


@dataclass(frozen=True)
class TrackerInfo:
    """A registry entry: the class, its parameter dataclass and its presets."""

    name: str
    cls: type
    params: Any                      # default parameter instance (the first preset)
    presets: dict[str, Any]
    summary: str

    @property
    def paper(self) -> str:
        return getattr(self.cls, "paper", "")

    @property
    def stages(self) -> tuple[str, ...]:
        return tuple(getattr(self.cls, "stages", ()))

    def describe(self) -> list[dict]:
        return describe(self.params)


_REGISTRY: dict[str, TrackerInfo] = {}
#: The built-in trackers, in the registry's order: name -> (the module registering it, its
#: summary line).  The CLI's choices and help come from here, and a run imports only its
#: tracker's module (:func:`tracker_info`): each module brings its own libraries (DLPF's the
#: scorer's scipy.optimize, PHD-MT's numba kernels), ~0.5 s a module.  The summaries are the
#: classes' (``tests/test_platform.py`` checks the two agree).
BUILTIN_TRACKERS = {
    "phd": ("pfscope.trackers.phd.tracker",
            "PHD-MT: particle PHD filter + modified K-means peaks + graph-matching association."),
    "mt": ("pfscope.trackers.phd.tracker",
           "MT: the graph-matching association run directly on the detections (PHD-MT's "
           "baseline)."),
    "passthrough": ("pfscope.trackers.passthrough",
                    "Reports every detection as a one-frame track (ids 1..N per frame); no "
                    "tracking."),
    "dlpf": ("pfscope.trackers.dlpf.tracker",
             "DLPF (jung2013): parents on LK motion classify one HOG window each; confirmed "
             "people are"),
    "dbn-phd": ("pfscope.trackers.dbn.tracker",
                "DBN-PHD: codebook blobs → particle PHD with a DBN colour+HOG likelihood → "
                "K-means →"),
    "phd-bgsub": ("pfscope.trackers.dbn.tracker",
                  "PHD on background-subtraction blobs without the DBN (DBN-PHD's baseline, "
                  "feng2015 \"PHD\")."),
}
#: Modules holding the built-in trackers; imported on first use of the registry, so that
#: ``pfscope --help`` does not pay for them and optional dependencies stay optional.
BUILTIN_MODULES = tuple(dict.fromkeys(m for m, _ in BUILTIN_TRACKERS.values()))
DEFAULT_TRACKER = "phd"

T = TypeVar("T", bound=type)


def register(cls: Optional[T] = None, *, presets: Optional[dict[str, Any]] = None,
             summary: Optional[str] = None) -> Any:
    """Class decorator putting a tracker in the registry under its ``name``:
    ``@register`` or ``@register(presets={"paper": PHDTrackerParams()})``.

    The class declares ``name``, ``paper``, ``stages``, ``needs_detections``, ``needs_image``
    and a ``Params`` dataclass (its defaults are the preset ``default`` when ``presets`` is not
    given), and its constructor takes ``(params, *, rng)``."""

    def deco(c: T) -> T:
        for attr in ("name", "paper", "stages", "needs_detections", "needs_image", "Params"):
            if not hasattr(c, attr):
                raise TypeError(f"tracker class {c.__name__} has no {attr!r}")
        name = c.name  # type: ignore[attr-defined]
        if name in _REGISTRY and _REGISTRY[name].cls is not c:
            raise ValueError(f"tracker name {name!r} is already registered")
        if not c.stages or len(set(c.stages)) != len(c.stages):  # type: ignore[attr-defined]
            raise TypeError(f"tracker {name!r}: stages must be a non-empty list of unique names")
        pre = dict(presets or {"default": c.Params()})  # type: ignore[attr-defined]
        doc = (summary or (c.__doc__ or "").strip().split("\n")[0]).strip()
        _REGISTRY[name] = TrackerInfo(name, c, next(iter(pre.values())), pre, doc)
        return c

    return deco(cls) if cls is not None else deco


def registry() -> dict[str, TrackerInfo]:
    """Every registered tracker (the built-ins are imported on first call), the built-ins
    first in :data:`BUILTIN_TRACKERS`' order whatever order they were imported in (as
    :func:`tracker_summaries`), then the others in the order they registered."""
    for mod in BUILTIN_MODULES:
        importlib.import_module(mod)
    out = {n: _REGISTRY[n] for n in BUILTIN_TRACKERS if n in _REGISTRY}
    out.update((n, i) for n, i in _REGISTRY.items() if n not in out)
    return out


def tracker_summaries() -> dict[str, str]:
    """``{name: summary}`` of every tracker, the built-ins first (:data:`BUILTIN_TRACKERS`),
    without importing them."""
    out = {n: summary for n, (_, summary) in BUILTIN_TRACKERS.items()}
    out.update({n: i.summary for n, i in _REGISTRY.items() if n not in out})
    return out


def tracker_info(name: str) -> TrackerInfo:
    """The registry entry of tracker ``name``, importing only its module when it is a
    built-in (all of them otherwise, then ValueError for an unknown name)."""
    if name not in _REGISTRY and name in BUILTIN_TRACKERS:
        importlib.import_module(BUILTIN_TRACKERS[name][0])
    if name in _REGISTRY:
        return _REGISTRY[name]
    reg = registry()
    if name not in reg:
        raise ValueError(f"unknown tracker {name!r}{did_you_mean(name, reg)}; choose one of "
                         f"{', '.join(reg)}")
    return reg[name]


def make_params(name: str, preset: Optional[str] = None, options: Optional[dict] = None) -> Any:
    """The parameters of tracker ``name``: ``preset`` (default: its first) with ``options``
    (``{"p_miss": "0.2"}``, strings converted) applied.  Bad names or values raise ValueError."""
    info = tracker_info(name)
    if preset is None:
        base = info.params
    elif preset in info.presets:
        base = info.presets[preset]
    else:
        raise ValueError(f"tracker {name!r} has no preset {preset!r}"
                         f"{did_you_mean(preset, info.presets)}; choose one of "
                         f"{', '.join(info.presets)}")
    return with_options(base, dict(options or {}))


def make_tracker(name: str, seed: int = 0, *, preset: Optional[str] = None,
                 **options) -> Tracker:
    """Build tracker ``name`` with its own ``numpy.random.Generator`` seeded by ``seed``."""
    info = tracker_info(name)
    params = make_params(name, preset, options)
    return info.cls(params, rng=np.random.default_rng(seed))


def param_origins(name: str, preset: Optional[str], params: Any,
                  fps: Optional[float] = None) -> dict[str, tuple[Any, str]]:
    """``{dotted name: (effective value, where it came from)}`` for ``params`` of tracker
    ``name`` run at ``fps``: ``preset NAME``, ``set`` (``--set`` / ``--params``), or, for a
    field the preset derives (or a setting nothing reads), why -- e.g. ``derived each frame
    from rate.gap_s (rate.per_second = true)`` with the value at ``fps``."""
    from .params import derived_from, leaves

    info = tracker_info(name)
    pname = preset or next(iter(info.presets), "default")
    base = {n: v for n, _, v in leaves(make_params(name, preset))}
    eff = params
    at_fps = getattr(params, "at_fps", None)
    if callable(at_fps):
        rate = getattr(params, "rate", None)
        eff = at_fps(float(fps or getattr(rate, "fallback_fps", 0) or 25.0))
    effective = {n: v for n, _, v in leaves(eff)}
    derived = derived_from(params)
    out: dict[str, tuple[Any, str]] = {}
    for n, _, v in leaves(params):
        if n in derived:
            why = derived[n].split(";")[0]
            out[n] = (effective[n], why + (f" at {fps:g} fps" if fps and "derived" in why
                                           else ""))
        elif v != base.get(n):
            out[n] = (effective[n], "set")
        else:
            out[n] = (effective[n], f"preset {pname}")
    return out


def params_config(params: Any) -> dict:
    """Parameters as a plain nested dict (for ``config()``)."""
    return to_dict(params)


__all__ = ["Tracker", "StepResult", "Rows", "TrackerInfo", "register", "registry",
           "tracker_summaries", "tracker_info", "make_params", "make_tracker", "params_config", "param_origins", "DEFAULT_TRACKER"]
