"""Shared test helpers: where the real data is, and reading recordings back."""

from __future__ import annotations

import os
from collections import defaultdict
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def data_root() -> Path | None:
    env = os.environ.get("PFSCOPE_DATA")
    for cand in ([Path(env)] if env else []) + [REPO.parent / "shared" / "data"]:
        if cand.is_dir():
            return cand
    return None


def sequence(name: str) -> Path:
    root = data_root()
    if root is None or not (root / name).is_dir():
        pytest.skip(f"{name} not found: set PFSCOPE_DATA to the folder holding it "
                    f"(default ../shared/data)")
    return root / name


def flat_params(d: dict, prefix: str = "") -> dict:
    """A nested parameter dict (``params.to_dict``) as ``{"part.name": value}``."""
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(flat_params(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


@pytest.fixture
def pets() -> Path:
    return sequence("PETS09-S2L1")


def read_rrd(path, footer: bool = True) -> dict:
    """Entity path -> list of (timeline values dict, columns dict) per row, read with
    ``rr.chunk.RrdReader``. ``footer=False``: a file that was never finished, read as pfscope's
    readers do (streamed; one a killed run left torn inside an entry up to its last whole
    entry)."""
    import pyarrow as pa
    import rerun as rr

    if footer:
        chunks = rr.chunk.RrdReader(str(path)).store().stream()
    else:
        from pfscope.viewer_app.rrdfile import open_chunks

        chunks, _, _ = open_chunks(path, note=False)
    out: dict = defaultdict(list)
    for ch in chunks:
        rb = ch.to_record_batch()
        names = rb.schema.names
        times = {t: rb.column(t).cast(pa.int64()).to_pylist() for t in ch.timeline_names
                 if t in names and t != "log_time"}
        cols = {n: rb.column(n).to_pylist() for n in names
                if n not in times and n not in ("log_time", "rerun.controls.RowId")}
        for i in range(rb.num_rows):
            out[ch.entity_path].append(({t: v[i] for t, v in times.items()},
                                        {c: v[i] for c, v in cols.items()}))
    return dict(out)


def rows_at(rec: dict, entity: str, frame: int) -> list:
    return [c for t, c in rec.get(entity, []) if t.get("frame") == frame]


def imported_in_fresh_process(code: str, module: str) -> bool:
    """Run ``code`` in a fresh interpreter and tell whether it left ``module`` imported (a
    start-up that must not pay for a heavy import)."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", f"{code}\nimport sys; print({module!r} in sys.modules)"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip().splitlines()[-1] == "True"
