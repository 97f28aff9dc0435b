"""Files a run writes: where partial output goes, which paths may be written at all, and a lock
so that two runs never write the same file.

Rules (DESIGN.md, "nothing is lost"):

- a run writes ``x.incomplete.rrd`` / ``x.txt.part`` and renames to ``x.rrd`` / ``x.txt`` only
  when it completed; a failed or interrupted run keeps ``*.incomplete.*``;
- an existing output that is not a regular file (a folder, a device such as ``/dev/full``, a
  FIFO, anything under ``/proc``, ``/sys`` or ``/dev``, a link to any of those) is refused, even
  with ``--force``: it is never written through or renamed over;
- :class:`OutputLock` makes a second run that names the same output fail at once with one
  line, instead of two runs interleaving their frames in one file.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Optional

from .errors import InputError

_SPECIAL_ROOTS = ("/proc", "/sys", "/dev")


def incomplete_path(path: str | os.PathLike) -> Path:
    """``x.rrd`` → ``x.incomplete.rrd``: where a failed or interrupted run's output stays."""
    p = Path(path)
    return p.with_name(f"{p.stem}.incomplete{p.suffix}")


def check_output(path: str | os.PathLike, force: bool, what: str = "recording") -> Path:
    """Validate an output path before anything is written: refuse special files and folders
    (always), an existing file without ``force``; create the parent folder; check it is
    writable.  Returns the path."""
    path = Path(path)
    real = Path(os.path.realpath(path))
    if any(str(real) == r or str(real).startswith(r + "/") for r in _SPECIAL_ROOTS):
        raise InputError(f"{path}: refusing to write a {what} into {real.parent} "
                         f"(not a regular file location)")
    if path.is_symlink() or path.exists():
        if path.is_dir():
            raise InputError(f"{path}: is a folder, not a {what} file")
        if not real.is_file():
            raise InputError(f"{path}: exists and is not a regular file; refusing to write "
                             f"the {what} there, even with --force")
        if not force:
            raise InputError(f"{path}: {what} exists; pass --force to overwrite it")
    writable_folder(path.parent if str(path.parent) else Path("."))
    return path


def writable_folder(folder: str | os.PathLike) -> Path:
    """Create ``folder`` (and its parents) if needed and check it is writable; one-line
    :class:`InputError` otherwise."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"{folder}: cannot create output folder ({e.strerror or e})") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(f"{folder}: output folder is not writable")
    return folder


def _file_ids(paths) -> dict:
    """(device, inode) → path of every existing regular file in ``paths``; a folder stands for
    every file in it and in its sub-folders (a MOT sequence: images, det, gt, seqinfo)."""
    ids: dict = {}

    def add(p: Path) -> None:
        try:
            st = os.stat(p)
        except OSError:
            return
        ids[(st.st_dev, st.st_ino)] = p

    for p in paths:
        if p is None:
            continue
        p = Path(p)
        if p.is_dir():
            for root, _dirs, files in os.walk(p):
                for f in files:
                    add(Path(root) / f)
        elif p.exists():
            add(p)
    return ids


def refuse_inputs(outputs, inputs) -> None:
    """Refuse (one line, even with ``--force``) an output that is one of the run's input files:
    ``outputs`` are (path, what) pairs, ``inputs`` files or folders the run reads.  Compared by
    device and inode, so a symlink or a hard link to an input is caught too."""
    ids = None
    for path, what in outputs:
        if path is None:
            continue
        try:
            st = os.stat(path)
        except OSError:
            continue  # does not exist yet: it is not an input
        if ids is None:
            ids = _file_ids(inputs)
        hit = ids.get((st.st_dev, st.st_ino))
        if hit is not None:
            raise InputError(f"{path}: is an input of this run ({hit}); refusing to write the "
                             f"{what} over it, even with --force")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class OutputLock:
    """``<folder>/.<name>.lock`` holding the owner's pid, created exclusively.  A lock left by
    a process that no longer exists (SIGKILL) is taken over; a live owner makes
    :meth:`acquire` raise a one-line :class:`InputError`."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.lock = self.path.with_name(f".{self.path.name}.lock")
        self._held = False

    def acquire(self) -> "OutputLock":
        for _ in range(2):
            try:
                fd = os.open(self.lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                owner = self._owner()
                if owner is not None and owner != os.getpid() and _alive(owner):
                    raise InputError(f"{self.path}: in use by another pfscope run (pid {owner}); "
                                     f"wait for it or choose another output") from None
                try:  # stale: its owner is gone
                    self.lock.unlink()
                except FileNotFoundError:
                    pass
                continue
            with os.fdopen(fd, "w") as fh:
                fh.write(str(os.getpid()))
            self._held = True
            return self
        raise InputError(f"{self.path}: could not lock the output ({self.lock})")

    def _owner(self) -> Optional[int]:
        try:
            return int(self.lock.read_text().strip() or "0") or None
        except (OSError, ValueError):
            return None

    def release(self) -> None:
        if self._held:
            self._held = False
            try:
                self.lock.unlink()
            except FileNotFoundError:
                pass

    def __enter__(self) -> "OutputLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


__all__ = ["incomplete_path", "check_output", "writable_folder", "refuse_inputs", "OutputLock"]
