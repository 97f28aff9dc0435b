"""The video tabs of a recording — title and entity paths — from one source.

The blueprint (:mod:`.blueprint`), ``pfscope info FILE.rrd --json`` (the ``tabs`` recording
property written from the same list) and the README's tab table
(``python -m pfscope.viewer_app.tabs``) all read :func:`single_tabs` / :func:`compare_tabs`,
so what the docs say a tab shows is what the viewer shows.

A tab is ``{"title": ..., "entities": [...], "lane": ...}``; entity paths are the Rerun paths
the 2D view includes (``video/phd/particles/updated`` ...; ``/**`` means the subtree).  In
``compare`` each stage tab holds one view per lane that has the stage (``lanes``).
"""

from __future__ import annotations

import json
import sys
from typing import Iterable, Optional, Sequence

#: Overlays every 2D view shows under the tracker's own entities.
BASE_2D = ("video", "video/detections", "video/gt")
ALL_STAGES = "All stages"


def view_entities(paths: Iterable[str], root: str = "") -> list[str]:
    """The entities a tab over ``paths`` (engine paths, ``phd/particles/**``) shows; where
    tracks are shown, their errors (misses, false positives, switches) too."""
    paths = list(paths)
    if "tracks/**" in paths:
        paths.append("metrics/**")
    return list(BASE_2D) + [f"{root}video/{p}" for p in paths]


def single_tabs(views: Sequence[tuple[str, Sequence[str]]]) -> list[dict]:
    """One tracker's tabs (its layout's ``views``), then "All stages"."""
    tabs = [{"title": t, "entities": view_entities(p)} for t, p in views]
    tabs.append({"title": ALL_STAGES, "entities": ["video/**"]})
    return tabs


def compare_tabs(lanes: Sequence[tuple[str, Sequence[tuple[str, Sequence[str]]]]]) -> list[dict]:
    """``lanes``: (lane root name, its tracker's views).  One tab per stage title (in the order
    titles first appear), each with one view per lane that has that stage, aligned on the same
    frame and stage; the lanes' entities under ``/<lane>/``."""
    order: list[str] = []
    by_title: dict[str, list[dict]] = {}
    for lane, views in lanes:
        for title, paths in views:
            if title not in by_title:
                order.append(title)
                by_title[title] = []
            by_title[title].append({"lane": lane,
                                    "entities": view_entities(paths, root=f"{lane}/")})
    return [{"title": t, "lanes": by_title[t],
             "entities": sorted({e for v in by_title[t] for e in v["entities"]})}
            for t in order]


def tracker_tabs(tracker: str) -> list[dict]:
    from .reporters import layout_for

    return single_tabs(layout_for(tracker).views)


def readme_table(trackers: Optional[Sequence[str]] = None) -> str:
    """The README's tab table (markdown): tracker, tab, what it shows (the engine paths)."""
    from .reporters import layout_for

    names = list(trackers or ("phd", "mt", "dlpf", "dbn-phd"))
    rows = ["| tracker | tab | what it shows | entities (under `video/`) |",
            "|---|---|---|---|"]
    for name in names:
        layout = layout_for(name)
        notes = dict(layout.notes)
        for title, paths in layout.views:
            shown = ", ".join(f"`{p}`" for p in paths)
            rows.append(f"| {name} | {title} | {notes.get(title, '')} | {shown} |")
        rows.append(f"| {name} | {ALL_STAGES} | every stage at once | `**` |")
    return "\n".join(rows)


def readme_summary(trackers: Optional[Sequence[str]] = None) -> str:
    """The README's short tab table: one row per tracker, its tabs in order with what each
    shows (the same layouts and notes as :func:`readme_table`)."""
    from .reporters import layout_for

    groups = [("phd",), ("mt",), ("dlpf",), ("dbn-phd", "phd-bgsub")]
    if trackers:
        groups = [(t,) for t in trackers]
    rows = ["| tracker | tabs (then All stages) |", "|---|---|"]
    for names in groups:
        layout = layout_for(names[0])
        notes = dict(layout.notes)
        cells = [f"**{t}** ({notes[t]})" if notes.get(t) else f"**{t}**"
                 for t, _ in layout.views]
        rows.append(f"| {', '.join(names)} | {'; '.join(cells)} |")
    return "\n".join(rows)


def to_property(tabs: list[dict]) -> dict:
    """The ``tabs`` recording property: the list as JSON (one string field)."""
    return {"json": json.dumps(tabs, separators=(",", ":"))}


def from_property(props: dict) -> Optional[list[dict]]:
    raw = (props.get("tabs") or {}).get("json")
    if not raw:
        return None
    try:
        return json.loads(raw)
    except ValueError:
        return None


def main(argv=None) -> int:
    """``python -m pfscope.viewer_app.tabs [TRACKER ...]``: print the README tab table."""
    args = list(sys.argv[1:] if argv is None else argv)
    print(readme_table(args or None))
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
