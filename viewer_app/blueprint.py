"""Default Rerun blueprints: the video with its overlays, the stage views a tracker declares,
time series and the text log."""

from __future__ import annotations

from typing import Optional, Sequence

import rerun.blueprint as rrb

#: Overlays every 2D view shows under the tracker's own entities.
BASE_2D = ["video", "video/detections", "video/gt"]


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
    tabs = []
    for title, paths in views:
        if "tracks/**" in paths:  # wherever tracks are shown, show their errors too
            paths = list(paths) + ["metrics/**"]
        contents = BASE_2D + [f"video/{p}" for p in paths]
        tabs.append(rrb.Spatial2DView(origin="video", contents=contents, name=title,
                                      **_bounds(size)))
    tabs.append(rrb.Spatial2DView(origin="video", name="All stages", **_bounds(size)))
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
    return rrb.Tabs(
        rrb.TextLogView(origin=events, name="Events", **kw),
        rrb.TextLogView(origin=log, name="Log"),
        rrb.TextDocumentView(origin=about, name="About"),
    )


def compare_blueprint(roots: Sequence[str],
                      size: Optional[tuple[int, int]] = None) -> rrb.Blueprint:
    """Several trackers side by side: one 2D view per tracker root over the shared video, and
    their metrics plotted together."""
    views = [rrb.Spatial2DView(origin="/", name=root, contents=[
        "/video", "/video/detections", "/video/gt", f"/{root}/video/tracks/**",
        f"/{root}/video/metrics/**"], **_bounds(size)) for root in roots]
    plots = [rrb.TimeSeriesView(origin="/", name=title, contents=[
        f"/{root}/plots/metrics/{key}" for root in roots])
        for title, key in (("OSPA", "ospa"), ("ID switches", "idsw"), ("False positives", "fp"),
                           ("Misses", "fn"), ("Estimated targets", "cardinality/estimated"))]
    return rrb.Blueprint(
        rrb.Vertical(rrb.Horizontal(*views), rrb.Horizontal(rrb.Tabs(*plots),
                                                            _logs("/", "/", "about", [
                                                                f"/{r}/events/**" for r in roots])),
                     row_shares=[3, 2]),
        *_panels(),
    )
