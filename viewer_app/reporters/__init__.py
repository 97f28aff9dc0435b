"""Reporters: how each tracker's stage data (:mod:`pfscope.trackers.report`) looks in Rerun.

One module per tracker (``phd.py``, ``mt.py`` ...) declares its blueprint (the stage views and
time series); everything else — colours, labels, which archetype an item becomes — is the
generic :class:`~.base.Reporter`, so a new tracker works in the viewer before it has a module
of its own, and one colour per track id holds everywhere.
"""

from __future__ import annotations

import importlib

from .base import Reporter, TrackerLayout

_MODULES = {"phd": "phd", "mt": "mt", "dlpf": "dlpf", "dbn-phd": "dbn",
            "phd-bgsub": "dbn"}


def layout_for(tracker_name: str) -> TrackerLayout:
    """The tracker's layout (its module's ``LAYOUT``), or a generic one."""
    mod = _MODULES.get(tracker_name)
    if mod is None:
        return TrackerLayout()
    return importlib.import_module(f"{__name__}.{mod}").LAYOUT


__all__ = ["Reporter", "TrackerLayout", "layout_for"]
