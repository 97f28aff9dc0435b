"""Frame sources: a MOTChallenge sequence folder, any OpenCV-readable video file, a folder of
images, and the built-in synthetic scene.  Each yields :class:`~trackers.types.Frame`s with a
1-based index and a timestamp in seconds.

Problems (missing ``seqinfo.ini``, a missing or unreadable image, an unreadable or empty video)
raise :class:`~trackers.errors.InputError` naming the file or frame.
"""

from __future__ import annotations

import configparser
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Optional

import cv2
import numpy as np

from ..errors import InputError
from ..types import Frame, blank_image
from .motio import MotTable, read_mot

IMAGE_EXTS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")


@dataclass(frozen=True)
class EncodedFrame(Frame):
    """A frame read from a JPEG file, with the file's bytes (``encoded``): a recorder may store
    them as they are instead of encoding the decoded pixels again."""

    encoded: Optional[bytes] = field(default=None, repr=False)


def _is_jpeg(data: bytes) -> bool:
    return data[:3] == b"\xff\xd8\xff"


@dataclass
class Source:
    """Base class. ``length`` is the number of frames when known; ``gt``/``det`` are the
    sequence's ground truth and public detections when it has them.

    :meth:`frames` yields each frame's image as an array it never writes to again (a new array
    per frame, or the same unchanging one): a recorder encodes a frame's picture while the next
    frame is read and tracked."""

    name: str
    fps: float
    length: Optional[int]
    width: int
    height: int
    gt: Optional[MotTable] = None
    det: Optional[MotTable] = None
    kind: str = "source"
    location: str = ""
    extra: dict = field(default_factory=dict)
    #: false for a source whose frames are blank stand-ins (a detections-only MOT folder)
    has_frames = True

    def frames(self, limit: Optional[int] = None) -> Iterator[Frame]:  # pragma: no cover
        raise NotImplementedError

    def describe(self) -> dict:
        d = dict(kind=self.kind, name=self.name, location=self.location, fps=self.fps,
                 length=self.length, width=self.width, height=self.height,
                 has_gt=self.gt is not None, has_det=self.det is not None)
        d.update(self.extra)
        return d


def _read_image(path: Path, index: int, size: Optional[tuple[int, int]] = None) -> np.ndarray:
    return _read_image_bytes(path, index, size)[0]


def _read_frame(path: Path, index: int, timestamp: float,
                size: Optional[tuple[int, int]] = None) -> Frame:
    """Frame ``index`` from the image file ``path``; a JPEG keeps its bytes
    (:class:`EncodedFrame`)."""
    img, data = _read_image_bytes(path, index, size)
    if _is_jpeg(data):
        return EncodedFrame(index, timestamp, img, encoded=data)
    return Frame(index, timestamp, img)


def _read_image_bytes(path: Path, index: int,
                      size: Optional[tuple[int, int]] = None) -> tuple[np.ndarray, bytes]:
    """Read and check one frame: a missing, truncated or undecodable file, or one whose size
    differs from ``size`` (width, height), is an :class:`InputError` naming file and frame.
    (OpenCV decodes a JPEG cut mid-file into a partly grey image with only a warning on
    stderr, so the end-of-image marker is checked first.)"""
    if not path.is_file():
        raise InputError(f"{path}: frame {index}: image file missing")
    try:
        data = path.read_bytes()
    except OSError as e:
        raise InputError(f"{path}: frame {index}: cannot read ({e.strerror or e})") from None
    if data[:2] == b"\xff\xd8" and b"\xff\xd9" not in data[-64:]:
        raise InputError(f"{path}: frame {index}: truncated JPEG (no end-of-image marker)")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR) if data else None
    if img is None:
        raise InputError(f"{path}: frame {index}: cannot decode image")
    if size is not None and (img.shape[1], img.shape[0]) != tuple(size):
        raise InputError(f"{path}: frame {index}: image is {img.shape[1]}x{img.shape[0]}, "
                         f"expected {size[0]}x{size[1]}")
    return img, data


def _check_rows_within(table: Optional[MotTable], length: int) -> None:
    """det/gt rows must name frames 1..seqLength; the first offending line is reported."""
    if table is None or not len(table) or (table.frame.min() >= 1 and table.last_frame <= length):
        return
    bad = int(table.frame[(table.frame < 1) | (table.frame > length)][0])
    lineno = "?"
    try:
        for i, line in enumerate(Path(table.path).read_text().splitlines(), start=1):
            head = line.split(",", 1)[0].strip()
            if head and int(float(head)) == bad:
                lineno = str(i)
                break
    except (OSError, ValueError):
        pass
    raise InputError(f"{table.path}:{lineno}: frame {bad} is outside the sequence's frames "
                     f"1..{length} (seqLength in seqinfo.ini)")


class MOTFolderSource(Source):
    """A MOTChallenge sequence: ``seqinfo.ini``, ``img1/000001.jpg ...``, optional
    ``gt/gt.txt`` and ``det/det.txt``.

    A folder with ``seqinfo.ini`` and ``det/det.txt`` but no image folder is a
    *detections-only* sequence (MOT15's KITTI-13 and TUD-Stadtmitte as shipped with their
    detections): its frames are blank images of the declared size
    (:func:`~trackers.types.blank_image`, ``Frame.has_pixels`` false), ``has_frames`` is false,
    and trackers that need pixels refuse it (:func:`~trackers.pipeline.run`)."""

    def __init__(self, root: str | os.PathLike, fps: Optional[float] = None):
        root = Path(root)
        ini = root / "seqinfo.ini"
        if not ini.is_file():
            raise InputError(f"{ini}: missing (a MOTChallenge folder needs seqinfo.ini)")
        cp = configparser.ConfigParser()
        try:
            cp.read(ini)
            seq = cp["Sequence"]
            name = seq.get("name", root.name)
            ini_fps = float(seq["frameRate"]) if "frameRate" in seq else None
            length = int(seq["seqLength"])
            width = int(seq.get("imWidth", "0"))
            height = int(seq.get("imHeight", "0"))
            self.im_dir = root / seq.get("imDir", "img1")
            self.im_ext = seq.get("imExt", ".jpg")
        except (KeyError, ValueError, configparser.Error) as e:
            raise InputError(f"{ini}: malformed seqinfo.ini ({e.__class__.__name__}: {e})") from None
        if ini_fps is not None and fps is not None:
            raise InputError(f"{root}: --fps does not apply to a MOTChallenge folder (its "
                             f"frameRate is in seqinfo.ini)")
        if ini_fps is None and fps is None:  # per-second settings depend on it: no guess
            raise InputError(f"{ini}: no frameRate; add frameRate=N to [Sequence] or give "
                             f"--fps N")
        fps = ini_fps if ini_fps is not None else fps
        if length <= 0 or fps <= 0:
            raise InputError(f"{ini}: seqLength and frameRate must be positive")
        gt_path, det_path = root / "gt" / "gt.txt", root / "det" / "det.txt"
        self.has_frames = self.im_dir.is_dir()
        if not self.has_frames and not det_path.is_file():
            raise InputError(f"{self.im_dir}: image folder missing (a folder without frames "
                             f"needs det/det.txt to be run on its detections)")
        if not self.has_frames and (width <= 0 or height <= 0):
            raise InputError(f"{ini}: a folder without frames needs imWidth and imHeight")
        gt = read_mot(gt_path, "gt") if gt_path.is_file() else None
        det = read_mot(det_path, "det") if det_path.is_file() else None
        _check_rows_within(gt, length)
        _check_rows_within(det, length)
        if width <= 0 or height <= 0:
            first = _read_image(self._path(1), 1)
            height, width = first.shape[:2]
        super().__init__(name=name, fps=fps, length=length, width=width, height=height, gt=gt,
                         det=det, kind="mot", location=str(root),
                         extra={} if self.has_frames else {"pixels": "none (detections only: blank frames)"})

    def _path(self, index: int) -> Path:
        return self.im_dir / f"{index:06d}{self.im_ext}"

    def frames(self, limit: Optional[int] = None, start: int = 1) -> Iterator[Frame]:
        """Frames ``start .. start + limit - 1`` (all from ``start`` when ``limit`` is None)."""
        n = self.length if limit is None else min(start - 1 + limit, self.length)
        blank = None if self.has_frames else blank_image(self.height, self.width)
        for k in range(max(1, start), n + 1):
            if blank is not None:
                yield Frame(k, (k - 1) / self.fps, blank)
            else:
                yield _read_frame(self._path(k), k, (k - 1) / self.fps, (self.width, self.height))


class VideoFileSource(Source):
    """Any video file OpenCV can read. Timestamps come from the container when it has them."""

    def __init__(self, path: str | os.PathLike):
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: no such file or folder")
        cap = cv2.VideoCapture(str(path))
        ok = cap.isOpened()
        ok_frame, first = cap.read() if ok else (False, None)
        if not ok or not ok_frame or first is None:
            cap.release()
            raise InputError(f"{path}: unreadable or empty video (OpenCV decoded no frame)")
        fps = cap.get(cv2.CAP_PROP_FPS)
        fps = float(fps) if fps and np.isfinite(fps) and fps > 0 else 25.0
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        cap.release()
        super().__init__(name=path.stem, fps=fps, length=n if n > 0 else None,
                         width=first.shape[1], height=first.shape[0], kind="video",
                         location=str(path))
        self.path = path

    def frames(self, limit: Optional[int] = None) -> Iterator[Frame]:
        cap = cv2.VideoCapture(str(self.path))
        try:
            k = 0
            last_ms, step_ms = 0.0, 0.0   # the last frame's container time and interval
            while limit is None or k < limit:
                ok, img = cap.read()
                if not ok or img is None:
                    if k == 0:
                        raise InputError(f"{self.path}: frame 1: cannot decode")
                    if self.length is not None and k < self.length \
                            and not self._covers_duration(k, last_ms, step_ms):
                        raise InputError(f"{self.path}: frame {k + 1}: the video ends after "
                                         f"{k} of the {self.length} frames its header "
                                         f"announces (truncated file?)")
                    return
                k += 1
                ms = cap.get(cv2.CAP_PROP_POS_MSEC)
                if k > 1 and np.isfinite(ms) and ms > last_ms:
                    step_ms = ms - last_ms
                last_ms = ms if np.isfinite(ms) else last_ms
                yield Frame(k, (k - 1) / self.fps, img)
        finally:
            cap.release()

    def _covers_duration(self, k: int, last_ms: float, step_ms: float) -> bool:
        """Whether ``k`` frames whose last one shows at ``last_ms`` reach the end of the
        stream: a variable-frame-rate video has fewer frames than its header's count
        (duration × the nominal rate) yet ends where the duration says; a truncated one ends
        early.  Within one frame interval (the last one seen, or the nominal one)."""
        if k < 2 or last_ms <= 0 or not self.length:
            return False  # no container times: the frame count is all there is
        duration_ms = 1000.0 * self.length / self.fps
        return last_ms + 2.0 * max(step_ms, 1000.0 / self.fps) >= duration_ms


class ImageFolderSource(Source):
    """A folder of images, taken in name order."""

    def __init__(self, root: str | os.PathLike, fps: float = 25.0):
        root = Path(root)
        files = sorted(p for p in root.iterdir() if p.suffix.lower() in IMAGE_EXTS and p.is_file())
        if not files:
            raise InputError(f"{root}: no images ({', '.join(IMAGE_EXTS)}) and no seqinfo.ini")
        first = _read_image(files[0], 1)
        super().__init__(name=root.name, fps=fps, length=len(files), width=first.shape[1],
                         height=first.shape[0], kind="images", location=str(root))
        self.files = files

    def frames(self, limit: Optional[int] = None, start: int = 1) -> Iterator[Frame]:
        start = max(1, start)
        files = self.files[start - 1:] if limit is None else self.files[start - 1:start - 1 + limit]
        for k, p in enumerate(files, start=start):
            yield _read_frame(p, k, (k - 1) / self.fps, (self.width, self.height))


class SyntheticSource(Source):
    """The built-in synthetic scene (:mod:`trackers.data.synthetic`), rendered on the fly."""

    def __init__(self, config=None):
        from .synthetic import SyntheticScene, demo_config

        self.scene = SyntheticScene(config or demo_config())
        c = self.scene.config
        super().__init__(name=f"synthetic-seed{c.seed}", fps=c.fps, length=c.frames,
                         width=c.width, height=c.height, gt=self.scene.gt, det=self.scene.det,
                         kind="synthetic", location="built-in",
                         extra=dict(scene=_dataclass_dict(c)))

    def frames(self, limit: Optional[int] = None) -> Iterator[Frame]:
        for f in self.scene.frames():
            if limit is not None and f.index > limit:
                return
            yield f


def sample_frames(source, n: int, first: int = 1, last: Optional[int] = None) -> list[np.ndarray]:
    """``n`` images evenly spaced over frames ``first..last`` of a recorded ``source`` (the
    whole clip when ``last`` is None and the length is known): an *offline* look at the clip,
    e.g. for a temporal-median background.  Folders read only the chosen files; a video is
    read through once (``grab`` skips the frames not chosen).  [] when the length is unknown
    (a stream: nothing can be sampled ahead)."""
    length = getattr(source, "length", None)
    last = length if last is None else (min(last, length) if length else last)
    if not last or n < 1 or last < first:
        return []
    idx = np.unique(np.round(np.linspace(first, last, min(n, last - first + 1))).astype(int))
    want = set(int(i) for i in idx)
    if isinstance(source, MOTFolderSource):
        return [_read_image(source._path(int(k)), int(k), (source.width, source.height))
                for k in idx]
    if isinstance(source, ImageFolderSource):
        return [_read_image(source.files[int(k) - 1], int(k), (source.width, source.height))
                for k in idx]
    if isinstance(source, VideoFileSource):
        out = []
        cap = cv2.VideoCapture(str(source.path))
        try:
            for k in range(1, int(idx[-1]) + 1):
                if not cap.grab():
                    break
                if k in want:
                    ok, img = cap.retrieve()
                    if ok and img is not None:
                        out.append(img)
        finally:
            cap.release()
        return out
    return [f.image for f in source.frames(int(idx[-1])) if f.index in want]


def _dataclass_dict(obj) -> dict:
    from dataclasses import asdict, is_dataclass

    return asdict(obj) if is_dataclass(obj) else dict(vars(obj))


def open_source(spec: str | os.PathLike | None, *, fps: Optional[float] = None,
                synthetic_config=None) -> Source:
    """Open ``spec``: None or ``"synthetic"`` -> the synthetic scene; a folder with
    ``seqinfo.ini`` or ``img1/`` -> MOT sequence; another folder -> images; a file -> video."""
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise InputError(f"--fps must be a positive number of frames per second, got {fps}")
    if spec is None or str(spec) == "synthetic":
        if fps is not None:
            raise InputError("--fps does not apply to the synthetic scene (its frame rate is "
                             "part of the scene)")
        return SyntheticSource(synthetic_config)
    path = Path(spec)
    if path.is_dir():
        if (path / "seqinfo.ini").exists() or (path / "img1").is_dir():
            return MOTFolderSource(path, fps=fps)
        return ImageFolderSource(path, fps=fps or 25.0)
    if path.exists():
        src = VideoFileSource(path)
        if fps:
            src.fps = fps
        return src
    raise InputError(f"{path}: no such file or folder")


def training_frames(source, frames, stride: int, command: str):
    """What a training command (``train-dbn``, ``train-classifier``) samples: ``(gt, first, last,
    chosen)`` — the source's ground truth, the first and last wanted frames, the set of every
    ``stride``-th wanted frame from the first.  No ground truth or no frames: one-line
    :class:`InputError` naming ``command``."""
    gt = getattr(source, "gt", None)
    if gt is None:
        raise InputError(f"{command}: {getattr(source, 'name', 'source')} has no ground truth "
                         "(gt/gt.txt) to take people from")
    wanted = sorted(set(int(f) for f in frames))
    if not wanted:
        raise InputError(f"{command}: no frames to train on")
    first, last = wanted[0], wanted[-1]
    return gt, first, last, set(f for f in wanted if (f - first) % max(1, stride) == 0)


def prefetch(frames: Iterator[Frame], depth: int = 2) -> Iterator[Frame]:
    """``frames``, read ``depth`` frames ahead on a thread: decoding (OpenCV releases the GIL)
    overlaps the tracking of the frame before.  Same frames in the same order; an error the
    reader meets (an :class:`InputError` naming the frame) is raised here after the frames
    before it.  Closing this generator (the run ends, fails or is interrupted) stops the reader
    within a fraction of a second; no wait is unbounded."""
    import queue
    import threading

    q: "queue.Queue" = queue.Queue(maxsize=max(1, depth))
    stop = threading.Event()
    done = object()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def read() -> None:
        try:
            for f in frames:
                if not put((f, None)):
                    return
        except BaseException as e:  # handed to the consumer, raised there
            put((done, e))
            return
        finally:
            close = getattr(frames, "close", None)
            if stop.is_set() and close is not None:
                try:
                    close()
                except Exception:
                    pass
        put((done, None))

    worker = threading.Thread(target=read, name="pfscope-frame-reader", daemon=True)
    worker.start()
    try:
        while True:
            try:
                item, err = q.get(timeout=0.5)
            except queue.Empty:
                if not worker.is_alive() and q.empty():
                    return  # the reader died without a word (cannot happen; never hang)
                continue
            if item is done:
                if err is not None:
                    raise err
                return
            yield item
    finally:
        stop.set()
        worker.join(timeout=2.0)
