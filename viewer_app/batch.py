"""``pfscope batch``: many recordings headlessly — every source × tracker (or parameter
variant) × seed — in parallel over the local cores.

    pfscope batch --sources A,B --trackers "phd,phd[p_miss=0.2],mt" --seeds 0,1 --out DIR
    pfscope batch SPEC.toml [--out DIR] [--workers N]

A TOML spec holds the same keys (command-line flags override it)::

    sources = ["../shared/data/PETS09-S2L1", "synthetic"]
    trackers = ["phd", "phd[p_miss=0.2]", "mt"]
    seeds = [0, 1]
    frames = "1:200"          # or 200
    level = "tracks"
    out = "runs/study1"
    workers = 2
    [set]
    "rate.gap_s" = 3

Per run ``DIR/<source>-<lane>-seed<S>``: ``.rrd`` (the recording), ``.txt`` (MOT tracks) and
``.json`` (the result: scores, timings, paths).  The ``.json`` is written last, only for a run
that completed: re-running the same command skips runs that have one (resume) and retries the
others; ``--force`` re-runs everything.  A failing run is reported (one line) and does not stop
the others; the exit status is 1 when any run failed.  At the end ``DIR/summary.csv`` and
``DIR/summary.json`` hold every run of the batch (finished earlier or now) and a table is
printed.

Runs go to a pool of ``--workers`` processes (default: the number of cores), each run in its
own process with single-threaded BLAS/OpenCV so runs do not fight over cores.

With ``--cluster tcp://HOST:PORT`` (or ``--backend dask --cluster ...``; spec keys ``cluster``
and ``backend``) the same runs go to an existing Dask distributed cluster instead
(``pip install "pfscope[distributed]"``); everything else is unchanged: the same files, resume,
summary, and a failing run (or a dying worker) does not stop the others.  The workers write
straight into ``--out``, so it must be a folder every worker sees at the same path (a shared
file system), and so must the sources; relative paths are made absolute here first.

With ``--backend ray`` (``pip install "pfscope[ray]"``) the runs are Ray tasks (one CPU each):
on the Ray instance this process is already connected to, else on ``--cluster ADDRESS``
(``ray://HOST:10001`` for Ray Client, ``HOST:6379`` or ``auto`` for a cluster this machine is
part of; an address starting with ``ray://`` implies ``--backend ray``), else on ``$RAY_ADDRESS``,
else on a Ray instance started here for the batch and stopped after it.  The same files, resume,
summary and failure rules as with Dask.

Ctrl-C or SIGTERM stops a batch on every backend the same way: queued runs never start,
running ones stop at their next frame with their files kept as ``*.incomplete.*``, the summary
says which runs finished, and the exit status is 130 (SIGINT) or 143 (SIGTERM); the same
command then resumes.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Optional

from pfscope.trackers.errors import InputError

SUMMARY_KEYS = ("MOTA", "MOTP", "IDF1", "HOTA", "IDSW", "FP", "FN", "OSPA")


@dataclass
class Job:
    source: str                 # as given ("synthetic" or a path)
    lane: str                   # tracker spec, e.g. "phd[p_miss=0.2]"
    seed: int
    out_dir: str
    frames: Optional[int] = None
    start: int = 1
    level: str = "tracks"
    detector: Optional[str] = None
    preset: Optional[str] = None
    options: dict = field(default_factory=dict)
    force: bool = False
    max_points: int = 3000
    identity: Optional[dict] = None   # run_identity(), computed once by run_batch

    @property
    def source_name(self) -> str:
        if self.source in ("", "synthetic"):
            return f"synthetic-seed{self.seed}"
        return Path(self.source).stem if Path(self.source).is_file() else Path(self.source).name

    @property
    def run_id(self) -> str:
        from .lanes import lane_name

        return f"{self.source_name}-{lane_name(self.lane)}-seed{self.seed}"

    def path(self, suffix: str) -> Path:
        return Path(self.out_dir) / f"{self.run_id}{suffix}"


BACKENDS = ("local", "dask", "ray")


def _init_worker() -> None:
    """Single-threaded BLAS/OpenCV/torch (a Dask or Ray worker; the local pool's workers get
    :func:`pfscope.trackers.jobs.init_worker`)."""
    from pfscope.trackers.jobs import single_thread_env

    single_thread_env()


def _fingerprint(source: str) -> dict:
    """What identifies the source's content without reading it: path, size and mtime of the
    file, or of every file in the folder and its sub-folders one level down."""
    if source in ("", "synthetic"):
        return {"source": "synthetic"}
    p = Path(source)
    if not p.exists():
        return {"source": os.path.abspath(source), "missing": True}
    if p.is_file():
        st = p.stat()
        return {"source": os.path.abspath(source), "size": st.st_size, "mtime": st.st_mtime_ns}
    import hashlib

    h = hashlib.sha256()
    n = 0
    for root in [p] + sorted(c for c in p.iterdir() if c.is_dir()):
        for f in sorted(root.iterdir()):
            if f.is_file():
                st = f.stat()
                h.update(f"{f.relative_to(p)}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
                n += 1
    return {"source": os.path.abspath(source), "files": n, "content": h.hexdigest()[:16]}


def run_identity(job: "Job") -> dict:
    """Everything that shapes a run's result (resume compares it): the source's path, sizes
    and mtimes, the tracker, the preset, every effective parameter (after --params/--set and
    the lane's own), the seed, the frames, the level, the detector and pfscope's version."""
    from pfscope.trackers.api import make_params
    from pfscope.trackers.params import leaves

    from .lanes import parse_lane
    from .run import _options_for

    ident: dict = {**_fingerprint(job.source), "lane": job.lane, "preset": job.preset,
                   "seed": job.seed, "start": job.start, "frames": job.frames,
                   "level": job.level, "detector": job.detector, "max_points": job.max_points,
                   "pfscope": _version()}
    try:
        lane = parse_lane(job.lane)
        params = make_params(lane.tracker, job.preset,
                             {**_options_for(lane.tracker, job.options, 1), **lane.options})
        ident["params"] = {n: repr(v) for n, _, v in leaves(params)}
    except Exception:  # noqa: BLE001 - the run itself reports it; the options then identify
        ident["params"] = {k: repr(v) for k, v in sorted(job.options.items())}
    return ident


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("pfscope")
    except Exception:  # noqa: BLE001
        return "unknown"


def identity_hash(ident: dict) -> str:
    import hashlib

    return hashlib.sha256(json.dumps(ident, sort_keys=True, default=str).encode()).hexdigest()


def changed_fields(old: dict, new: dict) -> list[str]:
    """Names of what differs between two identities (``params.NAME`` for a parameter)."""
    out = []
    for k in sorted(set(old) | set(new)):
        if k == "params" and isinstance(old.get(k), dict) and isinstance(new.get(k), dict):
            o, n = old[k], new[k]
            out += [f"params.{p}" for p in sorted(set(o) | set(n)) if o.get(p) != n.get(p)]
        elif old.get(k) != new.get(k):
            out.append(k)
    return out


def run_job(job: Job, stop=None) -> dict:
    """One run (in a worker process): never raises, returns its result row.  ``stop`` (an
    object with ``is_set()``; default: this process's job's stop event) ends it early: not
    started when already set, else stopped at the next frame with its files kept as
    ``*.incomplete.*``."""
    from pfscope.trackers.jobs import note_signal, stop_event

    from .api import record

    t0 = time.perf_counter()
    row = {"run": job.run_id, "source": job.source, "lane": job.lane, "seed": job.seed,
           "rrd": str(job.path(".rrd")), "tracks": str(job.path(".txt"))}
    ev = stop if stop is not None else stop_event()
    if ev is not None and ev.is_set():  # queued when the batch was stopped: do not start
        row.update(status="not run", rrd="", tracks="")
        return row
    try:
        synthetic = {}
        if job.source in ("", "synthetic"):
            synthetic = {"synthetic_seed": job.seed}
        res = record(job.source, tracker=job.lane, out=job.path(".rrd"),
                     tracks_out=job.path(".txt"), frames=job.frames, start=job.start,
                     level=job.level, seed=job.seed, detector=job.detector, preset=job.preset,
                     force=job.force, progress=False, max_points=job.max_points,
                     stop=ev, **synthetic, **job.options)
        scores = next(iter(res.scores.values()), {}) if res.scores else {}
        # stopped before its outputs were opened: nothing of it exists, as for a queued run
        # (the rule of _stopped_row: "interrupted" only with its partial files there)
        status = ("ok" if not res.interrupted
                  else "interrupted" if _leftovers(job) else "not run")
        row.update(status=status, frames=res.frames,
                   seconds=round(res.seconds, 3), fps=round(res.fps, 2), bytes=res.bytes,
                   rrd=str(res.out), tracks=str(res.tracks_out) if res.tracks_out else "",
                   **{k: scores[k] for k in SUMMARY_KEYS if k in scores})
        if status == "not run":
            row.update(rrd="", tracks="")
        if row["status"] == "ok":
            tmp = job.path(".json.part")
            ident = job.identity or run_identity(job)
            tmp.write_text(json.dumps({**row, "scores": scores, "identity": ident,
                                       "identity_hash": identity_hash(ident)}, indent=2,
                                      sort_keys=True, default=str))
            os.replace(tmp, job.path(".json"))
    except KeyboardInterrupt:  # a second Ctrl-C inside the run: it stopped where it was
        import signal

        note_signal(signal.SIGINT)
        row.update(status="interrupted", seconds=round(time.perf_counter() - t0, 3))
    except BaseException as e:  # noqa: BLE001 - one failing run must not stop the batch
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        row.update(status="failed", error=f"{type(e).__name__}: {msg}"[:300],
                   seconds=round(time.perf_counter() - t0, 3))
    return row


def _csv_list(text) -> list[str]:
    from .lanes import split_specs

    if text is None:
        return []
    if isinstance(text, (list, tuple)):
        return [str(x) for x in text]
    return split_specs(str(text))


def _parse_frames(v) -> tuple[int, Optional[int]]:
    if v is None:
        return 1, None
    if isinstance(v, tuple):
        return v[0], v[1] - v[0] + 1
    from .cli import parse_frames  # --frames N|FIRST:LAST, as every command reads it

    try:
        f = parse_frames(str(v))
    except ValueError as e:
        raise InputError(f"frames {e}") from None
    return (1, f) if isinstance(f, int) else (f[0], f[1] - f[0] + 1)


def plan(args) -> tuple[list[Job], Path, int]:
    """The jobs of a batch (spec file, then the flags given on the command line)."""
    spec: dict = {}
    if args.spec is not None:
        import tomllib

        try:
            spec = tomllib.loads(Path(args.spec).read_text())
        except FileNotFoundError:
            raise InputError(f"{args.spec}: no such batch spec") from None
        except tomllib.TOMLDecodeError as e:
            raise InputError(f"{args.spec}: not valid TOML ({e})") from None
        unknown = set(spec) - {"sources", "trackers", "seeds", "frames", "level", "out",
                               "workers", "set", "detector", "preset", "force", "max_points",
                               "backend", "cluster"}
        if unknown:
            raise InputError(f"{args.spec}: unknown key(s) {', '.join(sorted(unknown))}")

    def pick(flag, key, default=None):
        v = getattr(args, flag, None)
        return v if v not in (None, [], "") else spec.get(key, default)

    sources = _csv_list(pick("sources", "sources")) or ["synthetic"]
    lanes = _csv_list(pick("trackers", "trackers")) or ["phd"]
    seeds_raw = pick("seeds", "seeds", [0])
    try:
        seeds = [int(s) for s in (_csv_list(seeds_raw) if isinstance(seeds_raw, str)
                                   else seeds_raw)]
    except (TypeError, ValueError):
        raise InputError(f"--seeds {seeds_raw!r}: expected integers like 0,1,2") from None
    start, count = _parse_frames(pick("frames", "frames"))
    out = pick("out", "out")
    if not out:
        raise InputError("batch needs --out DIR (or 'out' in the spec)")
    if not isinstance(spec.get("set", {}), dict):
        raise InputError(f"{args.spec}: 'set' must be a table ([set] then NAME = VALUE lines), "
                         f"got {spec['set']!r}")
    for key, kind in (("workers", int), ("max_points", int), ("force", bool)):
        if key in spec and (not isinstance(spec[key], kind) or isinstance(spec[key], bool)
                            != (kind is bool)):
            raise InputError(f"{args.spec}: '{key}' must be {'true or false' if kind is bool else 'an integer'}, got {spec[key]!r}")
    options = {str(k): str(v) for k, v in (spec.get("set") or {}).items()}
    if args.set_options:
        from pfscope.trackers.params import parse_set

        try:
            options.update(parse_set(args.set_options))
        except ValueError as e:
            raise InputError(str(e)) from None
    from .lanes import parse_lanes

    parse_lanes(lanes)  # bad specs and duplicates fail before anything runs
    workers = int(pick("workers", "workers", 0) or 0) or (os.cpu_count() or 1)
    force = bool(args.force or spec.get("force", False))
    jobs = [Job(source=s, lane=ln, seed=seed, out_dir=str(out), frames=count, start=start,
                level=pick("level", "level", "tracks"), detector=pick("detector", "detector"),
                preset=pick("preset", "preset"), options=dict(options), force=force,
                max_points=int(spec.get("max_points", 3000)))
            for s in sources for ln in lanes for seed in seeds]
    ids = [j.run_id for j in jobs]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise InputError(f"two runs would write the same files: {', '.join(dup)}")
    args.cluster, args.backend = _pick_backend(pick("backend", "backend"),
                                               pick("cluster", "cluster"))
    return jobs, Path(out), workers


def _pick_backend(backend, cluster) -> tuple[Optional[str], str]:
    """(cluster address or None, backend name): a ``ray://`` address means Ray, any other
    address Dask."""
    implied = ("ray" if str(cluster).startswith("ray://") else "dask") if cluster else "local"
    backend = str(backend or implied).lower()
    if backend not in BACKENDS:
        raise InputError(f"--backend {backend!r}: expected one of {', '.join(BACKENDS)}")
    if backend == "dask" and not cluster:
        raise InputError("--backend dask needs --cluster ADDRESS (e.g. tcp://scheduler:8786)")
    if backend == "local" and cluster:
        raise InputError("--cluster is for --backend dask or ray (leave --backend out)")
    if backend == "dask" and str(cluster).startswith("ray://"):
        raise InputError(f"--cluster {cluster} is a Ray address: use --backend ray")
    return (str(cluster) if cluster else None), backend


def _import_dask():
    try:
        from dask.distributed import Client
    except ImportError:
        raise InputError('--cluster needs Dask distributed: pip install "pfscope[distributed]" '
                         '(or "dask[distributed]")') from None
    return Client


def _for_cluster(job: Job) -> Job:
    """The job with absolute paths, so a worker with another working folder finds them."""
    src = job.source  # abspath, not resolve: a symlink keeps its name, so the run id too
    if src not in ("", "synthetic") and Path(src).exists():
        src = os.path.abspath(src)
    return dataclasses.replace(job, source=src, out_dir=os.path.abspath(job.out_dir))


class _DaskStop:
    """The batch's stop as a worker sees it: the Dask ``Event`` named ``name`` (set by the
    client on Ctrl-C/SIGTERM), asked at most once a second."""

    def __init__(self, name: str, every: float = 1.0):
        self.name, self.every = name, every
        self._next, self._set = 0.0, False

    def is_set(self) -> bool:
        if not self._set and time.monotonic() >= self._next:
            self._next = time.monotonic() + self.every
            try:
                from distributed import Event

                self._set = bool(Event(self.name).is_set())
            except Exception:  # noqa: BLE001 - scheduler gone: the client's cancel ends us
                pass
        return self._set


def run_job_on_worker(job: Job, stop_name: Optional[str] = None) -> dict:
    """``run_job`` on a Dask or Ray worker: single-threaded BLAS/torch first, like the local
    pool; ``stop_name``: the Dask ``Event`` that stops the batch."""
    _init_worker()
    return run_job(job, stop=_DaskStop(stop_name) if stop_name else None)


def _died(j: Job, e: BaseException) -> dict:
    return {"run": j.run_id, "source": j.source, "lane": j.lane, "seed": j.seed,
            "status": "failed", "error": f"worker died: {type(e).__name__}: {e}"[:300]}


#: Seconds a cluster batch stopped by a signal waits for its running runs to finish their
#: files (as *.incomplete.*) and for its queued ones to report "not run".
CLUSTER_GRACE = 15.0


def _stopped_row(j: Job, e: BaseException) -> dict:
    """The row of a run that a stop signal cancelled: ``interrupted`` when it had started
    (its partial files are there), else ``not run``."""
    started = bool(_leftovers(j))
    return {**_died(j, e), "status": "interrupted" if started else "not run",
            **({} if started else {"error": ""})}


def _run_on_cluster(todo: list[Job], address: str, header,
                    report) -> tuple[dict[str, dict], Optional[int]]:
    """Submit every job to the Dask cluster at ``address``; rows by run id as they finish, and
    the stop signal if one came.  On Ctrl-C/SIGTERM the batch's Dask ``Event`` is set: queued
    runs return "not run" without starting, running ones stop at their next frame (files kept
    as ``*.incomplete.*``); after :data:`CLUSTER_GRACE` seconds what is left is cancelled."""
    from pfscope.trackers.jobs import StopOnSignal

    Client = _import_dask()
    try:
        client = Client(address, timeout="20s")
    except (OSError, TimeoutError) as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(f"--cluster {address}: cannot reach the Dask scheduler ({msg})") from None
    from dask.distributed import Event

    rows: dict[str, dict] = {}
    futs: dict = {}
    token = f"{os.getpid()}-{time.time_ns()}"
    stop = Event(f"pfscope-batch-stop-{token}", client=client)
    try:
        with StopOnSignal() as sigs:
            header(f"Dask cluster {address} ({sum(client.nthreads().values())} worker thread(s))")
            for j in todo:
                fut = client.submit(run_job_on_worker, _for_cluster(j), stop.name, pure=False,
                                    retries=0, key=f"pfscope-batch-{j.run_id}-{token}")
                futs[fut] = j
            unseen = True
            pending, deadline, i = set(futs), None, 0
            while pending:
                if sigs.signum is not None and deadline is None:
                    stop.set()
                    deadline = time.monotonic() + CLUSTER_GRACE
                if deadline is not None and time.monotonic() > deadline:
                    break
                done = [f for f in pending if f.done()]
                if not done:
                    time.sleep(0.2)
                    continue
                pending.difference_update(done)
                for fut in done:
                    j = futs[fut]
                    i += 1
                    try:
                        row = {**fut.result(), "source": j.source}
                    except BaseException as e:  # noqa: BLE001 - KilledWorker, lost worker
                        row = _stopped_row(j, e) if sigs.signum is not None else _died(j, e)
                    if row["status"] == "ok" and unseen and not j.path(".json").is_file():
                        unseen = False  # said once: resume needs the workers' files here
                        print(f"batch: warning: {j.path('.json')} was written by a worker but "
                              "is not visible here: --out must be a folder every worker "
                              "shares, or resume will not see finished runs", file=sys.stderr)
                    rows[j.run_id] = row
                    report(i, row)
            for fut in pending:  # past the grace period: cancelled
                rows[futs[fut].run_id] = _stopped_row(futs[fut], TimeoutError("cancelled"))
        return rows, sigs.signum
    finally:
        pending = [f for f in futs if not f.done()]
        if pending:
            client.cancel(pending)
        client.close()


def _import_ray():
    try:
        import ray
    except ImportError:
        raise InputError('--backend ray needs Ray: pip install "pfscope[ray]" (or "ray")') from None
    return ray


def _run_on_ray(todo: list[Job], address: Optional[str], header,
                report) -> tuple[dict[str, dict], Optional[int]]:
    """Run every job as a Ray task (1 CPU each) on the Ray instance this process is connected
    to, else on ``address`` / ``$RAY_ADDRESS``, else on one started here (and stopped after).
    On Ctrl-C/SIGTERM every task not finished is cancelled: a queued one never starts, a
    running one gets KeyboardInterrupt and keeps its files as ``*.incomplete.*``."""
    import logging

    from pfscope.trackers.jobs import StopOnSignal

    ray = _import_ray()
    started = False
    if not ray.is_initialized():
        try:
            ray.init(address=address or None, include_dashboard=False, log_to_driver=False,
                     logging_level=logging.WARNING)
        except Exception as e:  # noqa: BLE001 - ConnectionError, RuntimeError ...: one line
            msg = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise InputError(f"--backend ray: cannot start or reach Ray at "
                             f"{address or os.environ.get('RAY_ADDRESS') or 'a local instance'}"
                             f" ({msg})") from None
        started = True
    rows: dict[str, dict] = {}
    pending: list = []
    try:
        with StopOnSignal() as sigs:
            cpus = int(ray.cluster_resources().get("CPU", 0))
            where = address or ("a local Ray instance" if started else "the connected Ray cluster")
            header(f"Ray {where} ({cpus} CPU(s))")
            task = ray.remote(num_cpus=1, max_retries=0)(run_job_on_worker)
            refs = {task.remote(_for_cluster(j)): j for j in todo}
            pending = list(refs)
            i, deadline = 0, None
            while pending:
                if sigs.signum is not None and deadline is None:
                    for ref in pending:
                        ray.cancel(ref, force=False)  # queued: dropped; running: KeyboardInterrupt
                    deadline = time.monotonic() + CLUSTER_GRACE
                if deadline is not None and time.monotonic() > deadline:
                    break
                done, pending = ray.wait(pending, num_returns=1, timeout=0.2)
                for ref in done:
                    j = refs[ref]
                    i += 1
                    try:
                        row = {**ray.get(ref), "source": j.source}
                    except BaseException as e:  # noqa: BLE001 - cancelled, worker died, lost
                        if isinstance(e, KeyboardInterrupt):
                            raise
                        row = _stopped_row(j, e) if sigs.signum is not None else _died(j, e)
                    rows[j.run_id] = row
                    report(i, row)
            for ref in pending:  # past the grace period
                rows[refs[ref].run_id] = _stopped_row(refs[ref], TimeoutError("cancelled"))
        return rows, sigs.signum
    finally:
        for ref in pending:
            try:
                ray.cancel(ref, force=True)
            except Exception:  # noqa: BLE001 - best effort
                pass
        if started:
            ray.shutdown()


def run_batch(jobs: list[Job], out: Path, workers: int, *, quiet: bool = False,
              stream=None, cluster: Optional[str] = None,
              backend: Optional[str] = None) -> list[dict]:
    """Run ``jobs`` (skipping finished ones unless forced), write the summary, return rows.

    ``backend``: ``"local"`` (a process pool of ``workers``), ``"dask"`` (the Dask distributed
    scheduler at ``cluster``) or ``"ray"`` (Ray tasks: see the module docstring); by default
    ``"dask"`` when ``cluster`` is given, else ``"local"``."""
    cluster, backend = _pick_backend(backend, cluster)
    stream = stream or sys.stderr
    _check_out_dir(out)
    from pfscope.trackers.outputs import OutputLock

    lock = OutputLock(out / "batch")
    try:
        lock.acquire()
    except InputError:
        owner = lock._owner()
        raise InputError(f"{out}: another pfscope batch (pid {owner}) is writing into this "
                         f"folder; wait for it or choose another --out") from None
    try:
        return _run_batch_locked(jobs, out, workers, quiet=quiet, stream=stream,
                                 cluster=cluster, backend=backend)
    finally:
        lock.release()


def _check_out_dir(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder (--out names the batch's folder)")
    from pfscope.trackers.outputs import writable_folder

    writable_folder(out)


def _leftovers(j: Job) -> list[Path]:
    from pfscope.trackers.outputs import incomplete_path

    paths = [j.path(".rrd"), j.path(".txt")]
    return [p for p in paths + [incomplete_path(x) for x in paths] if p.exists()]


def _run_batch_locked(jobs, out, workers, *, quiet, stream, cluster, backend) -> list[dict]:
    rows: dict[str, dict] = {}
    todo = []
    notes: dict[str, str] = {}
    for j in jobs:
        if j.identity is None:
            j.identity = run_identity(j)
        done = j.path(".json")
        if done.is_file() and not j.force:
            try:
                prev = json.loads(done.read_text())
            except (OSError, ValueError):
                prev = {}
            old = prev.get("identity")
            if isinstance(old, dict) and prev.get("identity_hash") == identity_hash(j.identity):
                rows[j.run_id] = {**prev, "status": "skipped"}
                continue
            what = ", ".join(changed_fields(old, j.identity)[:6]) if isinstance(old, dict) \
                else "no run identity (an older pfscope)"
            notes[j.run_id] = f"re-run: changed {what}"
        elif _leftovers(j) and not j.force:
            notes[j.run_id] = "re-run: interrupted or failed earlier"
        # this batch holds the folder's lock: the run's own leftovers are its to replace
        # (a completed run only renames over them at the end)
        if _leftovers(j) or done.is_file():
            j = dataclasses.replace(j, force=True)
        todo.append(j)
    total, t0 = len(todo), time.perf_counter()

    def header(where: str) -> None:
        if not quiet:
            print(f"batch: {len(jobs)} runs, {len(jobs) - total} already finished, {total} to "
                  f"run on {where}", file=stream)

    def report(i, row):
        if quiet:
            return
        el = time.perf_counter() - t0
        eta = el / i * (total - i)
        what = (f"failed: {row.get('error')}" if row["status"] == "failed" else
                f"{row['status']} in {row.get('seconds', 0):.1f} s"
                + (f", MOTA {row['MOTA']:.3f}" if "MOTA" in row else ""))
        note = f" [{notes[row['run']]}]" if row["run"] in notes else ""
        print(f"batch [{i}/{total}] {row['run']}: {what}{note}  (elapsed {el:.0f} s, ETA "
              f"{eta:.0f} s)", file=stream)

    stopped = None
    if backend == "ray" and todo:
        got, stopped = _run_on_ray(todo, cluster, header, report)
        rows.update(got)
    elif backend == "ray":
        header(f"Ray {cluster or 'cluster'}")  # nothing to run: no need to start or connect
    elif cluster and todo:
        got, stopped = _run_on_cluster(todo, cluster, header, report)
        rows.update(got)
    elif cluster:
        header(f"Dask cluster {cluster}")  # nothing to run: no need to connect
    else:
        from pfscope.trackers.jobs import JobRunner

        n = min(workers, max(total, 1))
        header(f"{n} worker(s)")
        with JobRunner(n, in_process=n <= 1) as runner:
            i = 0
            for j, row in runner.each(run_job, todo):
                if isinstance(row, BaseException):
                    row = ({**_died(j, row), "status": "interrupted"} if runner.stopping
                           else _died(j, row))
                i += 1
                rows[j.run_id] = row
                report(i, row)
            stopped = runner.signum
    if stopped is not None:
        for j in todo:
            rows.setdefault(j.run_id, {"run": j.run_id, "source": j.source, "lane": j.lane,
                                       "seed": j.seed, "status": "not run"})
        if not quiet:
            import signal

            left = sum(r["status"] == "not run" for r in rows.values())
            print(f"batch: stopped by {signal.Signals(stopped).name}: {left} queued run(s) "
                  f"not started; running ones kept as *.incomplete.*; re-run the same "
                  f"command to resume", file=stream)
    ordered = [rows[j.run_id] for j in jobs]
    write_summary(ordered, out, wall=time.perf_counter() - t0)
    return ordered


def write_summary(rows: list[dict], out: Path, wall: float = 0.0) -> None:
    cols = ["run", "source", "lane", "seed", "status", "frames", "seconds", "fps",
            *SUMMARY_KEYS, "bytes", "rrd", "tracks", "error"]
    tmp = out / "summary.csv.part"
    with tmp.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k, "") for k in cols})
    os.replace(tmp, out / "summary.csv")
    tmp = out / "summary.json.part"
    tmp.write_text(json.dumps({"wall_seconds": round(wall, 3), "runs": [
        {k: v for k, v in r.items() if k != "scores"} for r in rows]}, indent=2,
        sort_keys=True, default=str))
    os.replace(tmp, out / "summary.json")


def format_table(rows: list[dict]) -> str:
    width = max([len("run")] + [len(r["run"]) for r in rows])
    head = f"{'run':<{width}}  {'status':<11} {'frames':>6} {'s':>7} " + " ".join(
        f"{k:>6}" for k in SUMMARY_KEYS)
    lines = [head]
    for r in rows:
        vals = []
        for k in SUMMARY_KEYS:
            v = r.get(k)
            vals.append(f"{'':>6}" if v is None else f"{int(v):>6d}" if k in ("IDSW", "FP", "FN")
                        else f"{v:>6.3f}" if k != "OSPA" else f"{v:>6.1f}")
        lines.append(f"{r['run']:<{width}}  {r['status']:<11} {r.get('frames', ''):>6} "
                     f"{r.get('seconds', 0) or 0:>7.1f} " + " ".join(vals))
    return "\n".join(lines)


def add_batch_parser(sub, add_tracker_options) -> None:
    b = sub.add_parser("batch", help="many recordings: sources × trackers × seeds, in parallel",
                       description="Record every source × tracker (or variant NAME[k=v]) × seed "
                                   "into DIR, in parallel over the local cores; resume skips "
                                   "finished runs; a summary CSV/JSON and a table at the end.")
    b.add_argument("spec", nargs="?", type=Path, default=None,
                   help="a TOML batch spec (flags given here override it)")
    b.add_argument("--sources", default=None, help="comma-separated sources (default synthetic)")
    b.add_argument("--trackers", default=None,
                   help="comma-separated trackers or variants, e.g. \"phd,phd[p_miss=0.2],mt\"")
    b.add_argument("--seeds", default=None, help="comma-separated seeds (default 0)")
    b.add_argument("--frames", default=None, metavar="N|FIRST:LAST",
                   help="N or FIRST:LAST (default: all)")
    b.add_argument("--level", default=None, choices=["tracks", "clusters", "particles"],
                   help="recording level (default tracks)")
    b.add_argument("--detector", default=None)
    b.add_argument("--out", type=Path, default=None, help="output folder")
    b.add_argument("--workers", type=int, default=None,
                   help="parallel processes (default: the number of cores)")
    b.add_argument("--cluster", default=None, metavar="ADDRESS",
                   help="run on an existing cluster: Dask, e.g. tcp://host:8786 (pip install "
                        "\"pfscope[distributed]\"), or Ray, e.g. ray://host:10001 (pip install "
                        "\"pfscope[ray]\"); --out must be shared")
    b.add_argument("--backend", default=None, choices=list(BACKENDS),
                   help="local process pool (default), dask (implied by --cluster) or ray "
                        "(implied by a ray:// address; without --cluster: the connected Ray, "
                        "$RAY_ADDRESS, or a Ray instance started for the batch)")
    b.add_argument("--force", action="store_true", help="re-run finished runs, overwrite outputs")
    b.add_argument("--json", action="store_true", help="print the summary as JSON")
    b.add_argument("--quiet", action="store_true", help="no per-run progress lines")
    add_tracker_options(b)


def cmd_batch(args) -> int:
    from pfscope.trackers.jobs import last_signal

    jobs, out, workers = plan(args)
    rows = run_batch(jobs, out, workers, quiet=args.quiet, cluster=args.cluster,
                     backend=args.backend)
    if args.json:
        print(json.dumps(rows, indent=2, sort_keys=True, default=str))
    else:
        print(format_table(rows))
        print(f"summary: {out / 'summary.csv'}  {out / 'summary.json'}")
    failed = [r for r in rows if r["status"] == "failed"]
    for r in failed:
        print(f"pfscope batch: {r['run']} failed: {r.get('error')}", file=sys.stderr)
    if last_signal() is not None and any(r["status"] in ("interrupted", "not run")
                                         for r in rows):
        return 128 + int(last_signal())
    return 1 if failed else 0


__all__ = ["Job", "plan", "run_batch", "run_job", "cmd_batch", "add_batch_parser"]
