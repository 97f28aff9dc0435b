"""``pfscope export FILE.rrd --out x.mp4 [--tab NAME] [--frames A:B]``: an annotated video of a
recording, drawn with OpenCV from the file alone (no viewer, no display, no GPU).

One video frame per recorded frame: the recorded picture with the chosen tab's content (the
tab's entities, as ``pfscope info FILE.rrd --json`` lists them): boxes with their colours and
shown labels (track ids), trails and edges, particle clouds in their recorded colours and
radii.  In a ``compare`` recording a tab holds one view per lane: the lanes are tiled (two
columns), each labelled with its name.  ``.gif`` writes an animated GIF (Pillow) instead,
at most :data:`GIF_WIDTH` pixels wide.

Reading: ``rr.chunk.RrdReader`` streams the file's chunks; only the tab's entities and the
video are kept, row by row with their ``frame`` and ``stage`` times.  An entity shows at a frame
its latest row at or before it (Rerun's latest-at), unless that row is a ``Clear``.

Drawing is vectorised where the counts are large: a cloud's points are stamped as small discs
by numpy indexing (one assignment per stamp offset, not one call per point); boxes and strips
(tens per frame) are drawn with ``cv2.rectangle`` / ``cv2.polylines``.
"""

from __future__ import annotations

import fnmatch
import os
import sys
from pathlib import Path
from typing import Optional

import cv2
import numpy as np

from pfscope.trackers.errors import InputError

#: Widest GIF frame (pixels); GIF frames are palette images, kept small.
GIF_WIDTH = 480
#: Frames per second of the video when the recording has no ``time`` timeline.
DEFAULT_FPS = 10.0


def _role_colors() -> dict[int, tuple[int, int, int, int]]:
    from .reporters.base import ROLES

    return {i: c for _, (i, c) in ROLES.items()}


def _unpack_colors(vals) -> Optional[np.ndarray]:
    """Rerun's packed 0xRRGGBBAA u32 colours -> (N, 4) uint8 RGBA."""
    if vals is None:
        return None
    a = np.asarray(vals, dtype=np.uint32).reshape(-1)
    out = np.empty((len(a), 4), dtype=np.uint8)
    out[:, 0] = (a >> 24) & 255
    out[:, 1] = (a >> 16) & 255
    out[:, 2] = (a >> 8) & 255
    out[:, 3] = a & 255
    return out


def _matches(entity: str, patterns: list[str]) -> bool:
    e = entity.lstrip("/")
    for p in patterns:
        p = p.lstrip("/")
        if p.endswith("/**"):
            base = p[:-3]
            if e == base or e.startswith(base + "/"):
                return True
        elif fnmatch.fnmatchcase(e, p):
            return True
    return False


class Recording:
    """The rows of a recording's video and of the chosen entities, read once."""

    def __init__(self, path: Path, patterns: list[str], note: bool = True):
        from .info import _open

        self.path = path
        self.video: dict[int, bytes] = {}
        self.times: dict[int, float] = {}
        #: entity -> list of (frame, stage, kind, row dict)
        self.rows: dict[str, list] = {}
        self.transforms: dict[str, tuple[float, float]] = {}
        chunks, _ = _open(path, note=note)
        for ch in chunks:
            ent = ch.entity_path
            want = ent == "/video" or _matches(ent, patterns)
            if not want:
                continue
            rb = ch.to_record_batch()
            names = rb.schema.names
            if "frame" not in names:   # static rows (a field's scale)
                if "Transform3D:scale" in names:
                    sc = rb.column("Transform3D:scale").to_pylist()
                    if sc and sc[-1]:
                        self.transforms[ent] = tuple(sc[-1][0][:2]) if isinstance(
                            sc[-1][0], (list, tuple)) else tuple(sc[-1][:2])
                continue
            frames = rb.column("frame").to_pylist()
            stages = rb.column("stage").to_pylist() if "stage" in names else [0] * len(frames)
            if ent == "/video":
                blobs = rb.column("EncodedImage:blob").to_pylist() \
                    if "EncodedImage:blob" in names else [None] * len(frames)
                tcol = rb.column("time").cast("int64").to_pylist() if "time" in names else None
                for i, (f, b) in enumerate(zip(frames, blobs)):
                    if f is None or not b:
                        continue
                    self.video[int(f)] = bytes(b[0]) if isinstance(b, list) else bytes(b)
                    if tcol is not None and tcol[i] is not None:
                        self.times[int(f)] = tcol[i] / 1e9
                continue
            cols = {n: rb.column(n).to_pylist() for n in names if ":" in n}
            if "Transform3D:scale" in cols:
                for sc in cols["Transform3D:scale"]:
                    if sc:
                        v = sc[0] if isinstance(sc[0], (list, tuple)) else sc
                        self.transforms[ent] = (float(v[0]), float(v[1]))
            out = self.rows.setdefault(ent, [])
            for i, f in enumerate(frames):
                if f is None:
                    continue
                row = {n: c[i] for n, c in cols.items() if c[i] is not None}
                if not row or set(row) <= {"Transform3D:scale"}:
                    continue
                kind = "clear" if any(n.startswith("Clear:") for n in row) else \
                    next(iter(row)).split(":")[0]
                out.append((int(f), int(stages[i] or 0), kind, row))
        for lst in self.rows.values():
            lst.sort(key=lambda r: (r[0], r[1]))
        self.frames = sorted(self.video)

    def at(self, entity: str, frame: int) -> Optional[tuple[str, dict]]:
        """The entity's latest row at or before ``frame`` (None when cleared or never)."""
        lst = self.rows.get(entity)
        if not lst:
            return None
        best = None
        for r in lst:  # rows per entity ~ frames: a bisect would do, lists are short enough
            if r[0] > frame:
                break
            best = r
        if best is None or best[2] == "clear":
            return None
        return best[2], best[3]


def _disc_offsets(r: int) -> np.ndarray:
    ys, xs = np.mgrid[-r:r + 1, -r:r + 1]
    keep = xs * xs + ys * ys <= r * r + r
    return np.stack([xs[keep], ys[keep]], axis=1)


def draw_points(img: np.ndarray, xy: np.ndarray, rgba: np.ndarray, radii: np.ndarray) -> None:
    """Stamp points as discs (alpha-blended, in order: later points over earlier), vectorised
    per radius and stamp offset."""
    h, w = img.shape[:2]
    if len(xy) == 0:
        return
    r_int = np.clip(np.round(radii).astype(np.int64), 0, 6)
    xi = np.round(xy[:, 0]).astype(np.int64)
    yi = np.round(xy[:, 1]).astype(np.int64)
    bgr = rgba[:, [2, 1, 0]].astype(np.float32)
    alpha = (rgba[:, 3:4].astype(np.float32) / 255.0)
    for r in np.unique(r_int):
        sel = np.flatnonzero(r_int == r)
        for dx, dy in _disc_offsets(int(r)):
            x, y = xi[sel] + dx, yi[sel] + dy
            ok = (x >= 0) & (x < w) & (y >= 0) & (y < h)
            s = sel[ok]
            x, y = x[ok], y[ok]
            a = alpha[s]
            img[y, x] = (img[y, x].astype(np.float32) * (1 - a) + bgr[s] * a).astype(np.uint8)


def _colors_for(row: dict, prefix: str, n: int, roles: dict) -> np.ndarray:
    col = _unpack_colors(row.get(f"{prefix}:colors"))
    if col is not None and len(col):
        return np.repeat(col, n, axis=0) if len(col) == 1 and n > 1 else col[:n]
    cids = row.get(f"{prefix}:class_ids")
    if cids:
        c = np.array([roles.get(int(i), (200, 200, 200, 255)) for i in cids], dtype=np.uint8)
        return np.repeat(c, n, axis=0) if len(c) == 1 and n > 1 else c[:n]
    return np.tile(np.array([200, 200, 200, 255], dtype=np.uint8), (n, 1))


def _show_labels(row: dict, kind: str) -> bool:
    """Rerun shows an archetype's labels unless its ``show_labels`` says otherwise."""
    show = row.get(f"{kind}:show_labels")
    if isinstance(show, list) and show:
        return bool(show[0])
    return True if show is None else bool(show)


def _thickness(row: dict, prefix: str, default: float = 1.0) -> int:
    r = row.get(f"{prefix}:radii")
    v = float(r[0]) if r else default
    return max(1, int(round(2 * v)))


def _blend_overlay(img: np.ndarray, layer: np.ndarray, mask: np.ndarray, alpha: float) -> None:
    img[mask] = (img[mask].astype(np.float32) * (1 - alpha)
                 + layer[mask].astype(np.float32) * alpha).astype(np.uint8)


def draw_entity(img: np.ndarray, kind: str, row: dict, roles: dict,
                scale: Optional[tuple[float, float]] = None) -> None:
    if kind == "Points2D":
        xy = np.asarray(row.get("Points2D:positions") or [], dtype=np.float32).reshape(-1, 2)
        n = len(xy)
        rgba = _colors_for(row, "Points2D", n, roles)
        r = row.get("Points2D:radii")
        radii = np.asarray(r if r else [1.5], dtype=np.float32)
        radii = np.repeat(radii, n) if len(radii) == 1 else radii[:n]
        draw_points(img, xy, rgba, radii)
    elif kind == "Boxes2D":
        c = np.asarray(row.get("Boxes2D:centers") or [], dtype=np.float32).reshape(-1, 2)
        hs = np.asarray(row.get("Boxes2D:half_sizes") or [], dtype=np.float32).reshape(-1, 2)
        n = min(len(c), len(hs)) if len(hs) > 1 else len(c)
        if len(hs) == 1 and n > 1:
            hs = np.repeat(hs, n, axis=0)
        rgba = _colors_for(row, "Boxes2D", n, roles)
        t = _thickness(row, "Boxes2D")
        labels = row.get("Boxes2D:labels") or []
        show = _show_labels(row, "Boxes2D")
        layer = img.copy()
        for i in range(n):
            p0 = tuple(int(v) for v in np.round(c[i] - hs[i]))
            p1 = tuple(int(v) for v in np.round(c[i] + hs[i]))
            col = tuple(int(v) for v in rgba[i][[2, 1, 0]])
            cv2.rectangle(layer, p0, p1, col, t, cv2.LINE_AA)
            if show and i < len(labels) and labels[i]:
                _label(layer, str(labels[i]), p0, col)
        a = float(rgba[:, 3].mean()) / 255.0 if n else 1.0
        mask = np.any(layer != img, axis=2)
        _blend_overlay(img, layer, mask, a)
    elif kind == "LineStrips2D":
        strips = row.get("LineStrips2D:strips") or []
        n = len(strips)
        rgba = _colors_for(row, "LineStrips2D", n, roles)
        t = _thickness(row, "LineStrips2D")
        labels = row.get("LineStrips2D:labels") or []
        show = _show_labels(row, "LineStrips2D")
        layer = img.copy()
        for i, s in enumerate(strips):
            pts = np.round(np.asarray(s, dtype=np.float32).reshape(-1, 2)).astype(np.int32)
            col = tuple(int(v) for v in rgba[i][[2, 1, 0]])
            if len(pts) >= 2:
                cv2.polylines(layer, [pts], False, col, t, cv2.LINE_AA)
            if show and i < len(labels) and labels[i] and len(pts):
                _label(layer, str(labels[i]), tuple(int(v) for v in pts[-1]), col)
        a = float(rgba[:, 3].mean()) / 255.0 if n else 1.0
        mask = np.any(layer != img, axis=2)
        _blend_overlay(img, layer, mask, a)
    elif kind == "EncodedImage":  # a dense field: RGBA PNG over the frame
        blob = row.get("EncodedImage:blob")
        if not blob:
            return
        data = np.frombuffer(bytes(blob[0] if isinstance(blob, list) else blob), np.uint8)
        im = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        if im is None or im.ndim != 3 or im.shape[2] != 4:
            return
        im = cv2.resize(im, (img.shape[1], img.shape[0]), interpolation=cv2.INTER_LINEAR)
        a = im[..., 3:4].astype(np.float32) / 255.0
        img[:] = (img.astype(np.float32) * (1 - a) + im[..., :3].astype(np.float32) * a
                  ).astype(np.uint8)


def _label(img: np.ndarray, text: str, at: tuple[int, int], color) -> None:
    x, y = at
    (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)
    y = max(th + 2, y)
    cv2.rectangle(img, (x, y - th - 3), (x + tw + 2, y + 1), (40, 40, 40), -1)
    cv2.putText(img, text, (x + 1, y - 2), cv2.FONT_HERSHEY_SIMPLEX, 0.5, color, 1,
                cv2.LINE_AA)


def _tab(tabs: list[dict], name: Optional[str]) -> dict:
    if not tabs:
        raise InputError("the recording lists no tabs (recorded before pfscope 0.2?); "
                         "re-record it to export it")
    if name is None:
        return tabs[0]
    for t in tabs:
        if t["title"].lower() == name.lower():
            return t
    raise InputError(f"no tab {name!r}; the recording's tabs: "
                     f"{', '.join(t['title'] for t in tabs)}")


def _entity_order(entities: list[str], patterns: list[str]) -> list[str]:
    """Entities of a view in the order its patterns name them (later drawn over earlier); the
    marks of errors (metrics) and track boxes last, so they are not hidden."""
    out = []
    for p in patterns:
        for e in sorted(entities):
            if e not in out and _matches(e, [p]):
                out.append(e)
    last = [e for e in out if "/metrics/" in e]
    return [e for e in out if e not in last] + last


def render_view(rec: Recording, frame: int, patterns: list[str], base: np.ndarray,
                title: Optional[str] = None) -> np.ndarray:
    img = base.copy()
    roles = _role_colors()
    ents = _entity_order([e for e in rec.rows if _matches(e, patterns)], patterns)
    for e in ents:
        got = rec.at(e, frame)
        if got is not None:
            draw_entity(img, got[0], got[1], roles, rec.transforms.get(e))
    if title:
        _label(img, title, (4, 4), (255, 255, 255))
    return img


def render_frame(rec: Recording, tab: dict, frame: int) -> Optional[np.ndarray]:
    blob = rec.video.get(frame)
    if blob is None:
        return None
    base = cv2.imdecode(np.frombuffer(blob, np.uint8), cv2.IMREAD_COLOR)
    if base is None:
        return None
    lanes = tab.get("lanes")
    if not lanes:
        return render_view(rec, frame, tab["entities"], base)
    tiles = [render_view(rec, frame, v["entities"], base, title=v["lane"]) for v in lanes]
    cols = 1 if len(tiles) == 1 else 2
    while len(tiles) % cols:
        tiles.append(np.zeros_like(base))
    rows = [np.hstack(tiles[i:i + cols]) for i in range(0, len(tiles), cols)]
    return np.vstack(rows)


def export(rrd, out, *, tab: Optional[str] = None, frames: Optional[tuple[int, int]] = None,
           progress: bool = True, force: bool = True) -> tuple[Path, int]:
    """Write the annotated video; returns (path, frames written)."""
    from pfscope.trackers.outputs import incomplete_path

    from .info import recording_info
    from .run import Progress, check_output

    rrd, out = Path(rrd), Path(out)
    if not rrd.is_file():
        raise InputError(f"{rrd}: no such recording")
    suffix = out.suffix.lower()
    if suffix not in (".mp4", ".avi", ".gif"):
        raise InputError(f"{out}: write .mp4, .avi or .gif")
    out = check_output(out, force=force, what="video")
    info = recording_info(rrd)
    t = _tab(info.get("tabs") or [], tab)
    patterns = list(t["entities"]) + [e for v in t.get("lanes") or [] for e in v["entities"]]
    rec = Recording(rrd, patterns, note=False)
    todo = [f for f in rec.frames if frames is None or frames[0] <= f <= frames[1]]
    cut = info.get("cut")   # torn inside an entry (a killed run): read up to the last whole one
    if not todo:
        raise InputError(f"{rrd}: no recorded frames" + (
            f" in {frames[0]}:{frames[1]} (recorded: {rec.frames[0]}..{rec.frames[-1]})"
            if frames and rec.frames else "") + (
            f" in its first {cut['read_bytes'] / 1e6:.1f} MB, up to where it is cut inside "
            f"an entry (a killed run?); `pfscope repair {rrd}` makes it whole" if cut else ""))
    if cut:
        print(f"pfscope: {cut['note']}", file=sys.stderr, flush=True)
    ts = [rec.times[f] for f in todo if f in rec.times]
    fps = DEFAULT_FPS
    if len(ts) > 1 and ts[-1] > ts[0]:
        fps = (len(ts) - 1) / (ts[-1] - ts[0])
    tmp = incomplete_path(out)
    bar = Progress(len(todo), f"export {out.name}", enabled=progress)
    gif: list = []
    writer = None
    n = 0
    try:
        for f in todo:
            img = render_frame(rec, t, f)
            if img is None:
                continue
            if suffix == ".gif":
                w = min(GIF_WIDTH, img.shape[1])
                h = int(round(img.shape[0] * w / img.shape[1]))
                gif.append(cv2.cvtColor(cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA),
                                        cv2.COLOR_BGR2RGB))
            else:
                if writer is None:
                    fourcc = cv2.VideoWriter_fourcc(*("mp4v" if suffix == ".mp4" else "MJPG"))
                    writer = cv2.VideoWriter(str(tmp), fourcc, float(fps),
                                             (img.shape[1], img.shape[0]))
                    if not writer.isOpened():
                        raise InputError(f"{out}: OpenCV cannot write this video format here")
                writer.write(img)
            n += 1
            bar.update(n)
        bar.close()
        if suffix == ".gif":
            try:
                from PIL import Image
            except ImportError:
                raise InputError("GIF export needs Pillow (pip install pillow); "
                                 "or write .mp4") from None
            ims = [Image.fromarray(a) for a in gif]
            ims[0].save(str(tmp), format="GIF", save_all=True, append_images=ims[1:],
                        duration=int(round(1000 / fps)), loop=0)
        else:
            assert writer is not None
            writer.release()
            writer = None
        os.replace(tmp, out)
    finally:
        if writer is not None:
            writer.release()
    return out, n


def cmd_export(args) -> int:
    path, n = export(args.file, args.out, tab=args.tab, frames=args.frames,
                     progress=not args.quiet, force=args.force)
    print(f"wrote {path} ({n} frames)")
    return 0


__all__ = ["export", "cmd_export", "Recording", "render_frame", "draw_points"]
