"""Detectors: one :class:`~trackers.types.Detections` type for every source of boxes.

A detector is a callable ``detector(frame) -> Detections`` with a ``name``:

- ``file``  — public detections from a MOT ``det.txt`` (:mod:`.file`), as maggio2007 §4 uses
  external detector output;
- ``hog``   — Dalal–Triggs HOG people detector (:mod:`.hog`), standing in for jung2013 §2.1's
  HOG/IKSVM pedestrian classifier;
- ``haar``  — Viola–Jones frontal-face cascade (:mod:`.haar`), the face detector of maggio2007 §4;
- ``bgsub`` — background-subtraction blobs (:mod:`.bgsub`), feng2015 §II-B's birth source.

:func:`make_detector` builds one by name for the CLI (``--detector file|hog|haar|bgsub``).
Bad names, options or inputs raise a one-line :class:`~trackers.errors.InputError`.
Image detectors are stateless except ``bgsub`` (its background model): one per sequence.
"""

from __future__ import annotations

import inspect
from typing import Protocol, runtime_checkable

from ..data.motio import MotTable
from ..errors import InputError
from ..types import Detections, Frame
from .bgsub import BackgroundSubtractionDetector
from .file import FileDetector
from .haar import HaarFaceDetector
from .hog import HOGPeopleDetector


@runtime_checkable
class Detector(Protocol):
    name: str

    def __call__(self, frame: Frame) -> Detections: ...


DETECTORS: tuple[str, ...] = ("file", "hog", "haar", "bgsub")

_CLASSES = {
    "file": FileDetector,
    "hog": HOGPeopleDetector,
    "haar": HaarFaceDetector,
    "bgsub": BackgroundSubtractionDetector,
}


def detector_options(name: str) -> dict[str, object]:
    """The options ``make_detector(name, **options)`` accepts, with their defaults."""
    if name not in _CLASSES:
        raise InputError(f"unknown detector {name!r}; choose one of {', '.join(DETECTORS)}")
    params = inspect.signature(_CLASSES[name]).parameters
    opts = {k: p.default for k, p in params.items() if k != "table"}
    if name == "file":
        opts["det_path"] = None
    return opts


def make_detector(name: str, *, det_table: MotTable | None = None, **options) -> Detector:
    """Build detector ``name`` (one of :data:`DETECTORS`) with keyword ``options``.

    ``file`` replays the det file at option ``det_path`` if given, else ``det_table`` (a
    source's ``det/det.txt``); option ``min_score`` drops rows scored below it.  Unknown names, unknown
    options and bad values raise :class:`~trackers.errors.InputError`.
    """
    key = str(name).strip().lower()
    if key not in _CLASSES:
        raise InputError(f"unknown detector {name!r}; choose one of {', '.join(DETECTORS)}")
    allowed = detector_options(key)
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise InputError(f"detector {key!r} has no option {', '.join(map(repr, unknown))}; "
                         f"options: {', '.join(allowed)}")
    if key == "file":
        det_path = options.pop("det_path", None)
        if det_path is not None:  # an explicit file wins over the source's own det.txt
            return FileDetector.from_path(det_path, **options)
        if det_table is None:
            raise InputError("detector 'file': the source has no det/det.txt (public detections); "
                             "use --detector hog|bgsub (or haar for faces)")
        return FileDetector(det_table, **options)
    return _CLASSES[key](**options)


__all__ = [
    "Detector", "DETECTORS", "make_detector", "detector_options", "FileDetector",
    "HOGPeopleDetector", "HaarFaceDetector", "BackgroundSubtractionDetector",
]
