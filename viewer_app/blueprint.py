"""Default Rerun blueprints: the video with its overlays, the stage views a tracker declares,
time series and the text log."""

from __future__ import annotations

from typing import Optional, Sequence

import rerun.blueprint as rrb

from .tabs import ALL_STAGES, BASE_2D  # noqa: F401 - BASE_2D re-exported


def _panels() -> tuple:
    """The time panel open (the timelines are how one navigates); the blueprint tree and the
    selection panel collapsed so the views get the width (a click on the top-right icons opens
    them; the recording's properties show in the selection panel)."""
    return (rrb.TimePanel(state="expanded"), rrb.BlueprintPanel(state="collapsed"),
            rrb.SelectionPanel(state="collapsed"))


def _bounds(size: Optional[tuple[int, int]]) -> dict:
    """Frame a 2D view on the image (``size`` = width, height): without it the view fits its
    content, and a particle or window off the image would shrink the video in that tab only."""
    if not size:
        return {}
    w, h = size
    return {"visual_bounds": rrb.VisualBounds2D(x_range=[0, w], y_range=[0, h])}


def metric_plots(root: str = "plots/metrics") -> list:
    """The metrics of each frame in two plots, as their scales differ: counts (true and
    estimated targets, false positives, misses, ID switches) and OSPA in pixels."""
    return [rrb.TimeSeriesView(origin=root, name="Metrics",
                               contents=[f"{root}/**", f"- {root}/ospa"]),
            rrb.TimeSeriesView(origin=root, name="OSPA", contents=[f"{root}/ospa"])]


def default_blueprint(views: Sequence[tuple[str, Sequence[str]]] = (),
                      plots: Sequence[tuple[str, Sequence[str]]] = (),
                      size: Optional[tuple[int, int]] = None,
                      metrics: bool = True) -> rrb.Blueprint:
    """``views``: (title, engine paths) pairs, each becoming a 2D view over the video that shows
    those paths (``"phd/particles/**"`` ...) on top of the frame; ``plots``: (title, paths)
    pairs of scalar series; ``size``: the frames' (width, height), which every 2D view is framed
    on; ``metrics``: add the metric plots (there is ground truth).  The tracker's views come
    first; the last tab shows everything."""
    from .tabs import single_tabs

    tabs = [rrb.Spatial2DView(origin="video", contents=t["entities"], name=t["title"],
                              **_bounds(size))
            if t["title"] != ALL_STAGES else
            rrb.Spatial2DView(origin="video", name=t["title"], **_bounds(size))
            for t in single_tabs(views)]
    series = []
    for title, paths in plots:
        series.append(rrb.TimeSeriesView(origin="plots", contents=[f"plots/{p}" for p in paths],
                                         name=title))
    if metrics:
        series += metric_plots()
    series.append(rrb.TimeSeriesView(origin="plots", name="All series"))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Tabs(*tabs, name="Video"),
            rrb.Vertical(rrb.Tabs(*series), _logs("log", "events", "about"),
                         row_shares=[3, 2]),
            column_shares=[7, 3],  # the video dominates
        ),
        *_panels(),
    )


def _logs(log: str, events: str, about: str, event_contents=None) -> rrb.Tabs:
    """The text panes: the failure index (Events: click a row to jump to its frame), the run's
    log, and the "About" note."""
    kw = {"contents": event_contents} if event_contents else {}
    # Rerun's text log is in time order: the severe events (ID switches, lost tracks) get
    # their own list first, so jumping through them needs no scrolling past the rest
    severe = rrb.archetypes.TextLogRows(filter_by_log_level=["ERROR", "WARN"])
    return rrb.Tabs(
        rrb.TextLogView(origin=events, name="Events: severe", rows=severe, **kw),
        rrb.TextLogView(origin=events, name="Events", **kw),
        rrb.TextLogView(origin=log, name="Log"),
        rrb.TextDocumentView(origin=about, name="About"),
    )


def compare_blueprint(roots: Sequence[str],
                      size: Optional[tuple[int, int]] = None,
                      lane_views: Optional[Sequence[Sequence[tuple[str, Sequence[str]]]]] = None
                      ) -> rrb.Blueprint:
    """Several trackers side by side.  ``lane_views``: each lane's tracker views (its layout);
    one video tab per stage title, holding that stage of every lane that has it (a grid:
    2 lanes side by side, 3-4 lanes two by two), all on the same frame and stage; without
    ``lane_views`` every lane shows its tracks.  Their metrics are plotted together."""
    from .tabs import compare_tabs

    if lane_views is None:
        lane_views = [(("Tracks", ("tracks/**",)),)] * len(roots)
    tabs = []
    for t in compare_tabs(list(zip(roots, lane_views))):
        views = [rrb.Spatial2DView(origin="/", name=f"{v['lane']}: {t['title']}",
                                   contents=[f"/{e}" for e in v["entities"]], **_bounds(size))
                 for v in t["lanes"]]
        cols = 2 if len(views) > 2 else len(views)
        tabs.append(rrb.Grid(*views, grid_columns=max(cols, 1), name=t["title"]))
    plots = [rrb.TimeSeriesView(origin="/", name=title, contents=[
        f"/{root}/plots/metrics/{key}" for root in roots])
        for title, key in (("OSPA", "ospa"), ("ID switches", "idsw"), ("False positives", "fp"),
                           ("Misses", "fn"), ("Estimated targets", "cardinality/estimated"))]
    return rrb.Blueprint(
        rrb.Vertical(rrb.Tabs(*tabs, name="Stages"),
                     rrb.Horizontal(rrb.Tabs(*plots),
                                    _logs("/", "/", "about", [f"/{r}/events/**" for r in roots])),
                     row_shares=[4, 1]),
        *_panels(),
    )
