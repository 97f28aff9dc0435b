"""Helpers shared by the benchmark scripts: finding the data, opening a source, timing
statistics, the machine description, tables and the ``--json`` output.

The benchmarks keep no frame loop of their own: every run goes through the engine's
:func:`pfscope.trackers.pipeline.run` (or ``viewer_app.run.record``, which uses it), with
hooks (and, for per-stage timing, a timing subclass of the tracker) doing the measuring.

Benchmarks are scripts run by hand (``.venv/bin/python benchmarks/<name>.py``), not tests.
Real data is looked up in ``$PFSCOPE_DATA`` and then in ``../shared/data`` relative to the
repository root, like the tests do; it is never copied into the repository.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import sys
from pathlib import Path
from typing import Iterable, Optional, Sequence

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:  # run from anywhere, installed or not
    sys.path.insert(0, str(REPO))

PETS = "PETS09-S2L1"
EXIT_NO_DATA = 2


class NoData(Exception):
    """The requested real sequence is not available (message says where we looked)."""


def data_roots() -> list[Path]:
    """Where real data is looked for, in order: ``$PFSCOPE_DATA``, ``<repo>/../shared/data``."""
    env = os.environ.get("PFSCOPE_DATA")
    return ([Path(env)] if env else []) + [REPO.parent / "shared" / "data"]


def pets_path() -> Path:
    """The PETS09-S2L1 MOT folder from the first data root that holds it."""
    roots = data_roots()
    for root in roots:
        if (root / PETS / "seqinfo.ini").is_file():
            return root / PETS
    raise NoData(f"{PETS} not found (looked in {', '.join(map(str, roots))}): set PFSCOPE_DATA "
                 f"to the folder holding {PETS}, or use --source synthetic")


def open_bench_source(spec: str, frames: Optional[int] = None, synthetic_frames: int = 150):
    """Open ``pets``, ``synthetic`` or a PATH (anything :func:`open_source` takes).

    The synthetic scene is built with ``frames`` frames when given (else ``synthetic_frames``),
    all other :class:`SceneConfig` fields at their defaults (seed 0)."""
    from pfscope.trackers.data.sources import open_source
    from pfscope.trackers.data.synthetic import SceneConfig

    if spec == "synthetic":
        return open_source("synthetic",
                           synthetic_config=SceneConfig(frames=frames or synthetic_frames))
    if spec == "pets":
        return open_source(pets_path())
    return open_source(spec)


def resolve_sources(specs: Optional[Sequence[str]]) -> list[str]:
    """Default (no ``--source``): PETS when its data is there, and the synthetic scene.
    PETS missing is only an error when it was asked for explicitly."""
    if specs:
        return list(dict.fromkeys(specs))
    try:
        pets_path()
        return ["pets", "synthetic"]
    except NoData as e:
        print(f"note: {e}; benchmarking the synthetic scene only", file=sys.stderr)
        return ["synthetic"]


def n_frames(source, frames: Optional[int]) -> int:
    """Frames to use: ``frames`` capped at the source length."""
    if source.length is None:
        if frames is None:
            raise SystemExit(f"{source.location}: length unknown, pass --frames N")
        return frames
    return source.length if frames is None else min(frames, source.length)


# ----------------------------------------------------------------------------- statistics

def median(xs: Iterable[float]) -> float:
    xs = list(xs)
    return statistics.median(xs) if xs else float("nan")


def fps(seconds: float, frames: int = 1) -> float:
    return frames / seconds if seconds > 0 else float("inf")


# ----------------------------------------------------------------------------- machine, output

def machine() -> dict:
    import numpy as np

    try:
        load = os.getloadavg()
    except OSError:
        load = None
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "loadavg_at_start": load,
            "python": platform.python_version(), "numpy": np.__version__,
            "platform": platform.platform()}


def print_machine(info: dict) -> None:
    load = info["loadavg_at_start"]
    load_s = ", ".join(f"{x:.2f}" for x in load) if load else "n/a"
    print(f"machine: {info['cpu']}, {info['cores']} cores, load average {load_s} "
          f"(shared machine: absolute numbers are indicative, ratios within one run hold better)")
    print(f"python {info['python']}, numpy {info['numpy']}")


def table(headers: Sequence[str], rows: Sequence[Sequence], aligns: Optional[str] = None) -> str:
    """A plain-text table; ``aligns`` one of 'l'/'r' per column (default: first left)."""
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    aligns = aligns or "l" + "r" * (len(headers) - 1)
    def fmt(r):
        return "  ".join(c.ljust(w) if a == "l" else c.rjust(w)
                         for c, w, a in zip(r, widths, aligns))
    lines = [fmt(cells[0]), "  ".join("-" * w for w in widths)]
    lines += [fmt(r) for r in cells[1:]]
    return "\n".join(lines)


def write_json(path: Optional[str], payload: dict) -> None:
    if not path:
        return
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(payload, indent=2, sort_keys=False, default=_json_default) + "\n")
    print(f"\nwrote {p}")


def _json_default(o):
    try:
        import numpy as np

        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
    except ImportError:  # pragma: no cover
        pass
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def command_line() -> str:
    return " ".join([".venv/bin/python", *sys.argv])
