"""Opening a recording for reading, including the one a killed run left torn.

A run killed while Rerun writes an entry (SIGKILL, power loss, a full disk) leaves a file that
ends inside that entry's payload.  Rerun 0.41 refuses such a file as a whole: its reader
(``rr.chunk.RrdReader``: ``.recordings()``, ``.stream()``, ``.store()``), ``rerun rrd verify``
and its viewer all stop with "Message payload ... exceeds file size", and the reader has no
option to stop at the last whole entry (only ``McapReader`` has ``recover=``).  ``rerun rrd
optimize`` (``pfscope repair``) does recover it.

So the readers here find the end of the last whole entry themselves, from the framing of the
file alone (never decoding a payload): after the 12-byte file header (``RRF2``, version,
options) every entry is a 16-byte header (kind u64, payload length u64, little-endian) and its
payload; kind 0 ends the stream (the footer follows it).  A torn file is read from a trimmed
copy (the whole entries; a temporary file, removed once read) and says so in one line; the
file itself is never written to.  A file without footer whose last entry is whole (a
killed run between two entries) Rerun streams as it is.
"""

from __future__ import annotations

import atexit
import os
import shutil
import struct
import sys
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Optional

from pfscope.trackers.errors import InputError

RRD_MAGIC = b"RRF2"
FILE_HEADER = 12          # magic, version, options
ENTRY_HEADER = 16         # kind (u64), payload length (u64), little-endian
END_KIND = 0              # the entry that ends the stream; the footer follows it
#: larger than any kind/length Rerun writes: framing we do not know is left to Rerun
_MAX_KIND, _MAX_LEN = 255, 1 << 40


@dataclass(frozen=True)
class Layout:
    """What the framing of an .rrd says.  ``whole``: bytes up to the end of its last whole
    entry; ``torn``: the file ends inside an entry's payload (``whole < size``); ``ended``: the
    stream's end entry was reached (the run finished its file)."""

    size: int
    whole: int
    torn: bool
    ended: bool


def scan(path) -> Layout:
    """Walk the entry headers of ``path`` (one seek and a 16-byte read per entry)."""
    with open(path, "rb") as fh:
        size = os.fstat(fh.fileno()).st_size
        if size < FILE_HEADER or fh.read(len(RRD_MAGIC)) != RRD_MAGIC:
            return Layout(size, size, False, False)   # Rerun says what is wrong with it
        off = FILE_HEADER
        while off + ENTRY_HEADER <= size:
            fh.seek(off)
            kind, n = struct.unpack("<QQ", fh.read(ENTRY_HEADER))
            if kind > _MAX_KIND or n > _MAX_LEN:
                return Layout(size, size, False, False)  # not a framing we know
            end = off + ENTRY_HEADER + n
            if end > size:
                return Layout(size, off, True, False)
            off = end
            if kind == END_KIND:
                return Layout(size, size, False, True)
        # a whole last entry (and maybe part of the next one's 16-byte header: Rerun skips it)
        return Layout(size, size, False, False)


def cut_note(path, layout: Layout) -> str:
    """The one line that says a torn file was read up to its last whole entry."""
    return (f"{path}: cut inside an entry (a killed run?): read up to its last whole entry, "
            f"{layout.whole / 1e6:.1f} of {layout.size / 1e6:.1f} MB; "
            f"`pfscope repair {path}` makes it whole")


_noted: set = set()


def note_cut(path, layout: Layout) -> None:
    """Print :func:`cut_note` on stderr, once per file per process."""
    key = (os.path.abspath(path), layout.size)
    if key in _noted:
        return
    _noted.add(key)
    print(f"pfscope: {cut_note(path, layout)}", file=sys.stderr, flush=True)


_copies: set = set()


@atexit.register
def _remove_copies() -> None:  # pragma: no cover - a reader left before its end
    for p in list(_copies):
        _remove(p)


def _remove(p: str) -> None:
    _copies.discard(p)
    try:
        os.unlink(p)
    except OSError:
        pass


def trimmed_copy(path, length: int) -> str:
    """The first ``length`` bytes of ``path`` in a temporary file (removed by :func:`release`
    or at exit): a copy of the file cut to ``length``."""
    fd, tmp = tempfile.mkstemp(prefix="pfscope-whole-", suffix=".rrd")
    _copies.add(tmp)
    os.close(fd)
    try:
        shutil.copyfile(path, tmp)         # (the kernel's copy where the system has one)
        short = length - os.path.getsize(tmp)
        if short > 0:
            raise OSError(f"the file shrank while it was read ({short} bytes short)")
        os.truncate(tmp, length)
    except OSError as e:
        _remove(tmp)
        raise InputError(f"{path}: cut inside an entry, and no room for a trimmed copy to "
                         f"read ({e}); try `pfscope repair {path}`") from None
    return tmp


def release(copy: Optional[str]) -> None:
    if copy:
        _remove(copy)


def _first_line(e: Exception) -> str:
    s = str(e)
    return (s.splitlines()[0] if s else type(e).__name__)[:160]


def open_chunks(path, *, note: bool = True):
    """``(chunks, footer, layout)``: a lazy iterator over the recording's chunks (through the
    footer's index when the file has one, else streamed; a torn file up to its last whole
    entry, with one line on stderr when ``note``), whether the file has its footer, and its
    :class:`Layout` when it was scanned (a file without footer), else None.  Errors are
    :class:`InputError` with one line."""
    import rerun as rr

    path = Path(path)

    def reader(p):
        with warnings.catch_warnings():
            # a file without footer is streamed below: Rerun's "no footer/manifest ... legacy
            # format" warning would only add two lines of noise
            warnings.filterwarnings("ignore", message=".*no footer")
            return rr.chunk.RrdReader(str(p))

    try:
        r = reader(path)
    except Exception as e:  # noqa: BLE001 - any reader error is the file's fault
        raise InputError(f"{path}: not a readable Rerun recording ({_first_line(e)})") from None
    try:
        return r.store().stream(), True, None
    except Exception:  # noqa: BLE001 - no footer (killed run): stream what is there
        pass
    layout = scan(path)
    copy = None
    if layout.torn:
        if layout.whole <= FILE_HEADER:
            raise InputError(f"{path}: cut inside its first entry: nothing recorded to read")
        copy = trimmed_copy(path, layout.whole)
        r = reader(copy)
    try:
        stream = r.stream()
    except Exception as e:  # noqa: BLE001 - cut short in a way we do not know
        release(copy)
        msg = _first_line(e).replace(str(copy), str(path)) if copy else _first_line(e)
        if "No recording store" in msg:
            raise InputError(f"{path}: holds no recorded data") from None
        raise InputError(f"{path}: cut short, not readable as it is ({msg}); try "
                         f"`pfscope repair {path}`") from None
    if copy and note:
        note_cut(path, layout)
    return _chunks(stream, path, copy), False, layout


def _chunks(stream, path, copy) -> Iterator:
    try:
        for ch in stream:
            yield ch
    except Exception as e:  # noqa: BLE001 - cut short inside an entry we did not see
        raise InputError(f"{path}: cut short, not readable as it is ({_first_line(e)}); try "
                         f"`pfscope repair {path}`") from None
    finally:
        release(copy)


def check_whole_for_viewer(path) -> None:
    """The Rerun viewer refuses a torn file outright: one line saying what to do instead."""
    path = Path(path)
    try:
        layout = scan(path)
    except OSError:
        return                  # the viewer says what is wrong
    if layout.torn:
        raise InputError(f"{path}: cut inside an entry (a killed run?); the Rerun viewer does "
                         f"not open such a file: `pfscope repair {path}` writes a whole copy "
                         f"to view")


__all__ = ["Layout", "scan", "open_chunks", "cut_note", "note_cut", "check_whole_for_viewer",
           "RRD_MAGIC"]
