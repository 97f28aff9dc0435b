"""pfscope: particle-filter multi-target visual tracking that shows its work.

    import pfscope
    res = pfscope.record("../shared/data/PETS09-S2L1", tracker="phd", out="x.rrd",
                         level="particles", p_miss=0.1)
    for fr in pfscope.stream("synthetic", tracker="mt", frames=50):
        ...

The engine is ``pfscope.trackers`` (never imports rerun), the app ``pfscope.viewer_app``.
This file is installed as the top-level ``pfscope`` package (pyproject maps it from
``viewer_app/_pfscope``); it stays light: ``record``/``stream`` load the app on first use, so
``import pfscope.trackers`` still pulls in no rerun.
"""

from __future__ import annotations

from pfscope.trackers import __version__  # the one version string (pyproject.toml repeats it)
__all__ = ["record", "stream", "RecordResult", "FrameResult", "__version__"]


def __getattr__(name: str):
    if name in ("record", "stream", "RecordResult", "FrameResult"):
        from pfscope.viewer_app import api

        return getattr(api, name)
    raise AttributeError(f"module 'pfscope' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + ["record", "stream", "RecordResult", "FrameResult"])
