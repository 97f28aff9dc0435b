"""The job runner shared by ``pfscope batch`` and ``pfscope tune``: a pool of worker processes
that is stopped as one job.

- **Signals.**  Inside :class:`JobRunner` SIGINT and SIGTERM (to this process or to its whole
  process group) stop the job: queued items are cancelled, running ones are asked to stop
  (the shared stop event; a recording then finishes its files as ``*.incomplete.*``), the
  workers get ``grace`` seconds to end, then SIGTERM, then SIGKILL.  :meth:`JobRunner.map`
  then raises :class:`Interrupted` (its ``signum`` gives the exit status 128 + signum);
  :meth:`JobRunner.each` reports the cancelled items as not run and says so in ``signum``.
- **No orphans.**  Every worker watches its parent: when the parent is gone (SIGKILL, a
  crash) the worker sets the stop event, gives its current item a few seconds to finish its
  files and exits.  Workers ignore SIGINT outside a run (a Ctrl-C to the group is the parent's
  to handle; no worker prints a traceback).
- **One thread per run.**  Workers run with single-threaded BLAS/OpenCV/torch so runs do not
  fight over cores.

The engine side: :func:`stop_requested` is what a long computation in a worker (or in this
process, ``workers == 1``) polls to stop early.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from concurrent.futures import FIRST_COMPLETED, Future, wait
from typing import Any, Callable, Iterable, Iterator, Optional

#: The stop event of this process's job (a worker's: the parent's shared event).
_STOP: Any = None
#: The last stop signal this process received (SIGINT/SIGTERM), for the exit status.
_LAST_SIGNAL: Optional[int] = None


def note_signal(signum: int) -> None:
    """Remember ``signum`` as the signal that stopped this process's work (exit 128 + it)."""
    global _LAST_SIGNAL
    _LAST_SIGNAL = int(signum)


def last_signal() -> Optional[int]:
    return _LAST_SIGNAL


def exit_status(default: int = 130) -> int:
    """128 + the last stop signal (130 for SIGINT, 143 for SIGTERM); ``default`` without one."""
    return 128 + _LAST_SIGNAL if _LAST_SIGNAL else default


def stop_requested() -> bool:
    """True once this process's job was asked to stop (polled between frames)."""
    return _STOP is not None and _STOP.is_set()


def stop_event():
    """The stop event of this process's job (an object with ``is_set``), or None."""
    return _STOP


class Interrupted(Exception):
    """The job was stopped by a signal before every item finished."""

    def __init__(self, signum: int, done: int = 0, total: int = 0):
        self.signum = int(signum)
        name = signal.Signals(self.signum).name
        super().__init__(f"interrupted by {name} ({done} of {total} finished)")

    @property
    def exit_status(self) -> int:
        return 128 + self.signum


def single_thread_env() -> None:
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    try:
        import cv2

        cv2.setNumThreads(1)
    except Exception:  # noqa: BLE001
        pass
    try:
        import torch

        torch.set_num_threads(1)
    except Exception:  # noqa: BLE001
        pass


#: Seconds a worker whose parent died gives its current item before it exits.
ORPHAN_GRACE = 5.0


def _watch_parent(parent: int, poll: float = 0.5) -> None:
    while True:
        time.sleep(poll)
        if os.getppid() != parent:
            if _STOP is not None:
                _STOP.set()
            time.sleep(ORPHAN_GRACE)
            os._exit(143)


def init_worker(stop, parent: int) -> None:
    """Pool initializer: single-threaded libraries, the shared stop event, SIGINT ignored
    outside a run, and a thread that ends this worker when its parent is gone."""
    global _STOP
    single_thread_env()
    _STOP = stop
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_sigterm)
    threading.Thread(target=_watch_parent, args=(parent,), name="pfscope-watch-parent",
                     daemon=True).start()


def _worker_sigterm(signum, _frame):
    # outside a run (a run installs its own handler): the parent or the group wants us gone
    if _STOP is not None:
        _STOP.set()
    os._exit(128 + signum)


class StopOnSignal:
    """While inside (main thread only), SIGINT and SIGTERM do not raise: they record the signal
    (:attr:`signum`, :func:`note_signal`) and call ``on_signal(first)``.  A job whose work runs
    elsewhere (a Dask or Ray cluster) polls :attr:`signum` to stop its queue; the
    :class:`JobRunner` stops its pool the same way."""

    def __init__(self, on_signal: Optional[Callable[[bool], None]] = None):
        self.signum: Optional[int] = None
        self.on_signal = on_signal
        self._old: dict = {}

    def handler(self, signum, _frame=None) -> None:
        first = self.signum is None
        self.signum = int(signum)
        note_signal(signum)
        if self.on_signal is not None:
            self.on_signal(first)

    def __enter__(self) -> "StopOnSignal":
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self.handler)
        return self

    def __exit__(self, *exc) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()


class JobRunner:
    """Runs items through ``fn`` here (``workers <= 1``) or over a spawn process pool, as one
    job that signals stop (module docstring).  Use as a context manager::

        with JobRunner(4) as jr:
            for item, result in jr.each(fn, items): ...   # completion order; cancelled: skipped
            results = jr.map(fn, items)                  # in order; Interrupted on a signal
    """

    def __init__(self, workers: int, *, grace: float = 10.0, in_process: Optional[bool] = None):
        self.workers = max(1, int(workers))
        self.grace = float(grace)
        self.in_process = self.workers <= 1 if in_process is None else bool(in_process)
        self.pool = None
        self._ctx = None
        self._stop = None
        self._signals = StopOnSignal(self._on_signal)

    # ------------------------------------------------------------------ signals
    def _on_signal(self, first: bool) -> None:
        if self._stop is not None:
            self._stop.set()
        if not first and self.in_process:
            raise KeyboardInterrupt  # a second Ctrl-C: really out

    def _handler(self, signum, frame=None) -> None:
        self._signals.handler(signum, frame)

    @property
    def signum(self) -> Optional[int]:
        return self._signals.signum

    @property
    def stopping(self) -> bool:
        return self.signum is not None

    def __enter__(self) -> "JobRunner":
        global _STOP
        import multiprocessing as mp

        self._ctx = mp.get_context("spawn")
        if self.in_process:
            self._stop = threading.Event()
            self._prev_stop, _STOP = _STOP, self._stop
        else:
            self._stop = self._ctx.Event()
        self._signals.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        global _STOP
        try:
            self.close()
        finally:
            self._signals.__exit__()
            if self.in_process:
                _STOP = self._prev_stop

    def stop_event(self):
        return self._stop

    # ------------------------------------------------------------------ the pool
    def _pool(self):
        if self.pool is None:
            from concurrent.futures import ProcessPoolExecutor

            self.pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=self._ctx,
                                            initializer=init_worker,
                                            initargs=(self._stop, os.getpid()))
        return self.pool

    def each(self, fn: Callable, items: Iterable) -> Iterator[tuple[Any, Any]]:
        """Yield ``(item, result)`` as items finish; a worker that died yields its exception
        as the result.  After a stop signal nothing new starts: cancelled items are not
        yielded (``self.stopping`` is then True)."""
        items = list(items)
        if self.in_process:
            for it in items:
                if self.stopping:
                    return
                yield it, fn(it)
            return
        pool = self._pool()
        futs: dict[Future, Any] = {pool.submit(fn, it): it for it in items}
        pending = set(futs)
        deadline = None
        while pending:
            if self.stopping and deadline is None:
                for f in pending:
                    f.cancel()
                pending = {f for f in pending if not f.cancelled()}
                deadline = time.monotonic() + self.grace
            if deadline is not None and time.monotonic() > deadline:
                self._terminate()
                # what is left died with the workers: their results are exceptions
                deadline = float("inf")
            done, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            for f in done:
                if f.cancelled():
                    continue
                try:
                    res = f.result()
                except BaseException as e:  # noqa: BLE001 - a worker died (killed, OOM)
                    res = e
                yield futs[f], res

    def map(self, fn: Callable, items: Iterable) -> list:
        """``[fn(item) ...]`` in order; raises :class:`Interrupted` after a stop signal and
        :class:`~pfscope.trackers.errors.RunFailed` when a worker died."""
        from concurrent.futures.process import BrokenProcessPool

        from .errors import RunFailed

        items = list(items)
        index = {id(it): i for i, it in enumerate(items)}
        out: list = [None] * len(items)
        n = 0
        for it, res in self.each(fn, items):
            if isinstance(res, BaseException) and not self.stopping:
                if isinstance(res, BrokenProcessPool):
                    raise RunFailed(f"a worker process died ({res}); out of memory? try fewer "
                                    f"workers") from None
                raise res
            out[index[id(it)]] = res
            n += 1
        if self.stopping:
            raise Interrupted(self.signum or signal.SIGINT, n, len(items))
        return out

    def _terminate(self) -> None:
        procs = list(getattr(self.pool, "_processes", {}).values()) if self.pool else []
        for p in procs:
            if p.is_alive():
                p.terminate()
        t0 = time.monotonic()
        for p in procs:
            p.join(timeout=max(0.0, 3.0 - (time.monotonic() - t0)))
        for p in procs:
            if p.is_alive():
                p.kill()
                p.join(timeout=2.0)

    def close(self) -> None:
        """Shut the pool down: queued items cancelled, workers reaped (terminated when still
        running after ``grace`` seconds of a stop)."""
        if self.pool is None:
            return
        pool, self.pool = self.pool, None
        if self.stopping:
            # queued items cancelled; an idle worker ends on the pool's shutdown message at
            # once, a busy one when its item returns (it polls the stop event): wait for that
            # at most `grace` seconds, then end the rest
            procs = list((getattr(pool, "_processes", None) or {}).values())
            pool.shutdown(wait=False, cancel_futures=True)
            t0 = time.monotonic()
            for p in procs:
                p.join(timeout=max(0.0, self.grace - (time.monotonic() - t0)))
            for p in procs:
                if p.is_alive():
                    p.terminate()
            for p in procs:
                p.join(timeout=3.0)
                if p.is_alive():
                    p.kill()
                    p.join(timeout=2.0)
        pool.shutdown(wait=True, cancel_futures=True)


__all__ = ["JobRunner", "StopOnSignal", "Interrupted", "init_worker", "single_thread_env", "stop_requested",
           "stop_event", "note_signal", "last_signal", "exit_status"]
