"""The platform every tracker plugs into: the registry, the typed stage contract, the one
pipeline, what a failed run leaves behind, the stage timeline with several trackers, and a
tracker that needs the image and no detector."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import pytest

from conftest import read_rrd
from pfscope.trackers.api import StepResult, make_tracker, register, registry
from pfscope.trackers.data.sources import open_source
from pfscope.trackers.data.synthetic import SceneConfig
from pfscope.trackers.params import param
from pfscope.trackers.pipeline import BaseHook, TracksFileHook, run
from pfscope.trackers.report import (ITEM_TYPES, Boxes, Field, Mask, Points, StageLog)
from pfscope.trackers.types import Detections, Frame, TrackSet
from pfscope.viewer_app.run import RecordOptions, record


def _scene(frames=12, **kw):
    return open_source("synthetic", synthetic_config=SceneConfig(
        frames=frames, targets=4, clutter=2.0, width=320, height=240, seed=2, **kw))


# ----------------------------------------------------------------------------- a reporter written
# only to the protocol: it knows StepResult, Stage and the item types, nothing of any tracker.

class ProtocolReporter(BaseHook):
    def __init__(self):
        self.seen: dict[str, set] = {}
        self.frames = 0

    def begin(self, info):
        self.declared = {name: tuple(t.stages) for name, t in info.trackers.items()}

    def on_frame(self, report):
        self.frames += 1
        for lane, res in report.results.items():
            assert isinstance(res, StepResult)
            assert isinstance(res.tracks, TrackSet)
            names = [s.name for s in res.stages]
            positions = [self.declared[lane].index(n) for n in names]  # ValueError if undeclared
            assert positions == sorted(positions) and len(set(names)) == len(names)
            for stage in res.stages:
                for item in stage.items:
                    assert isinstance(item, ITEM_TYPES), type(item)
                    self.seen.setdefault(lane, set()).add(type(item).__name__)
            for f, ts in res.rows:
                assert 1 <= f <= report.frame.index and isinstance(ts, TrackSet)


@pytest.mark.parametrize("name", sorted(registry()))
def test_every_registered_tracker_works_with_a_protocol_only_reporter(name):
    rep = ProtocolReporter()
    res = run(_scene(), [make_tracker(name, seed=1)], level="particles", hooks=[rep])
    assert rep.frames == 12 and res.outcome.status == "completed"
    assert rep.seen.get(name), f"{name} reported no stage data"
    info = registry()[name]
    assert info.paper and info.stages
    from pfscope.trackers.params import leaves
    assert [r["name"] for r in info.describe()] == [n for n, _, _ in leaves(info.params)]


def test_the_registry_describes_every_parameter():
    for name, info in registry().items():
        for row in info.describe():
            assert row["doc"], f"{name}: parameter {row['name']} has no documentation"


def test_the_built_in_catalogue_is_the_registry_and_a_run_imports_its_tracker_only():
    """The CLI's choices and help come from BUILTIN_TRACKERS without importing the trackers:
    the same names, order and summaries as the registered classes; building the parser and
    looking up dlpf imports neither PHD-MT's nor DBN-PHD's module."""
    import subprocess
    import sys

    from pfscope.trackers.api import BUILTIN_TRACKERS, tracker_summaries

    reg = registry()
    assert list(BUILTIN_TRACKERS) == [n for n in reg if n in BUILTIN_TRACKERS]
    assert {n: s for n, (_, s) in BUILTIN_TRACKERS.items()} == \
        {n: reg[n].summary for n in BUILTIN_TRACKERS}
    assert all(reg[n].cls.__module__ == m for n, (m, _) in BUILTIN_TRACKERS.items())
    assert list(tracker_summaries()) == list(reg)
    code = ("import sys; import pfscope.viewer_app.cli as c; c.build_parser(); "
            "from pfscope.trackers.api import tracker_info; tracker_info('dlpf'); "
            "print(sorted(m for m in sys.modules if m.startswith('pfscope.trackers.') "
            "and m.endswith('.tracker')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "['pfscope.trackers.dlpf.tracker']"


def test_stage_log_enforces_the_declared_order():
    log = StageLog(("a", "b"), "particles")
    log.stage("b")
    with pytest.raises(ValueError, match="order"):
        log.stage("a")
    with pytest.raises(ValueError, match="not in the tracker's stage list"):
        StageLog(("a",)).stage("z")
    with pytest.raises(ValueError, match="id_kind"):
        Points("p", np.zeros((2, 2)), ids=[1, 2])
    with pytest.raises(ValueError, match="3 values for 2"):
        Boxes("b", np.zeros((2, 4)), values={"m": [1, 2, 3]})
    with pytest.raises(ValueError, match="class 2 has no name"):
        Mask("m", np.full((2, 2), 2), classes=("bg", "fg"))


def test_level_none_log_makes_the_same_stages_when_read():
    """A level-None log records the frame and StepResult makes the Stage tuple on the first
    read of ``stages``: the very stages a log at a level makes of the same calls (scalars,
    events, an empty stage); the checks still raise in the call."""
    from pfscope.trackers.report import Event, PendingStages, Scalar, Stage

    def fill(log):
        log.stage("a")
        log.scalar("x", 3)
        log.event("e", "hello", "DEBUG")
        log.stage("b")
        log.stage("c")
        log.scalar("y", np.float32(0.5))
        log.scalar("z", 2.25)

    lazy, eager = StageLog(("a", "b", "c"), None), StageLog(("a", "b", "c"), "tracks")
    fill(lazy)
    fill(eager)
    pending, want = lazy.result(), eager.result()
    assert isinstance(pending, PendingStages) and type(want) is tuple
    res = StepResult(TrackSet.empty(), [], pending)
    assert "stages" not in res.__dict__                 # nothing made yet
    assert type(res.stages) is tuple and res.stages == want and res.stages is res.stages
    assert want == (Stage("a", (Scalar("x", 3.0), Event("e", "hello", "DEBUG"))),
                    Stage("b"), Stage("c", (Scalar("y", 0.5), Scalar("z", 2.25))))
    assert pending == want and list(pending) == list(want) and len(pending) == 3
    assert StepResult(TrackSet.empty()).stages == () and StepResult(TrackSet.empty()).rows == []
    log = StageLog(("a", "b"), None)
    with pytest.raises(ValueError, match="before any stage"):
        log.scalar("x", 1.0)
    log.stage("b")
    with pytest.raises(ValueError, match="order"):
        log.stage("a")
    with pytest.raises(TypeError, match="not a report item"):
        log.add("text")
    with pytest.raises(ValueError, match="severity"):
        log.event("e", "m", "LOUD")


def test_phd_level_none_stages_are_the_levels_scalars_and_events():
    """PHD-MT at level None (a run's pipeline: stages made only if read) reports the same
    scalars and events frame by frame as at level 'tracks'."""
    from pfscope.trackers.report import Event, Scalar

    got = {}
    for level in (None, "tracks"):
        seen = []

        class Keep(BaseHook):
            def on_frame(self, report):
                res = report.results["phd"]
                assert ("stages" in res.__dict__) == (level is not None)
                seen.append([(st.name, [(type(i).__name__, i.path, getattr(i, "value", None),
                                         getattr(i, "message", None)) for i in st.items
                                        if isinstance(i, (Scalar, Event))])
                             for st in res.stages])

        run(_scene(20), {"phd": make_tracker("phd", 0, preset="practical")}, level=level,
            hooks=[Keep()], keep_rows=False, score=False)
        got[level] = seen
    assert got[None] == got["tracks"]
    flat = [i for frame in got[None] for _, items in frame for i in items]
    assert any(k == "Event" for k, *_ in flat) and sum(k == "Scalar" for k, *_ in flat) > 80


# ----------------------------------------------------------------------------- a tracker that needs
# the image and no detections, with its own stages and every new vocabulary item

@dataclass(frozen=True)
class BrightParams:
    threshold: int = param(128, "grey level above which a pixel is foreground")
    fail_at: int = param(0, "raise at this frame (0: never); for testing failure handling")


@register
class BrightBlobTracker:
    """Test tracker: one box around the bright pixels of the frame."""

    name = "test-bright"
    paper = "-"
    stages = ("threshold", "motion", "children")
    needs_detections = False
    needs_image = True
    Params = BrightParams

    def __init__(self, params: Optional[BrightParams] = None, *, rng=None):
        self.params = params or BrightParams()
        self.detections_seen = []

    def step(self, frame: Frame, detections: Optional[Detections],
             level: Optional[str] = None) -> StepResult:
        self.detections_seen.append(detections)
        if frame.index == self.params.fail_at:
            raise RuntimeError("simulated bug")
        log = StageLog(self.stages, level)
        grey = frame.image.mean(axis=2)
        mask = grey > self.params.threshold
        log.stage("threshold")
        if log.wants("clusters"):
            log.add(Mask("bright/mask", mask.astype(np.uint8), classes=("dark", "bright")))
        log.stage("motion")
        if log.wants("particles"):
            log.add(Field("bright/grey", grey[::4, ::4], unit="grey level", vmin=0, vmax=255))
        log.stage("children")
        ys, xs = np.nonzero(mask)
        tracks = TrackSet.empty()
        if len(xs):
            tracks = TrackSet([1], [[xs.min(), ys.min(), xs.max() - xs.min() + 1,
                                     ys.max() - ys.min() + 1]])
            if log.wants("particles"):
                pts = np.c_[xs[::50], ys[::50]]
                log.add(Points("bright/children", pts, ids=np.ones(len(pts)), id_kind="track",
                               values={"score": np.ones(len(pts))}))
        log.scalar("bright/pixels", int(mask.sum()))
        log.event("bright", "frame done", "DEBUG")
        return StepResult(tracks, [(frame.index, tracks)], log.result())

    def finish(self):
        return []

    def config(self):
        return {"tracker": self.name}


def test_detector_free_tracker_gets_no_detector_and_the_image(tmp_path):
    tr = make_tracker("test-bright")
    hook = ProtocolReporter()
    res = run(_scene(), [tr], level="particles", hooks=[hook])
    assert res.outcome.status == "completed"
    assert all(d is None for d in tr.detections_seen)       # no detector was run for it
    assert {"Mask", "Field", "Points", "Scalar", "Event"} <= hook.seen["test-bright"]
    # and it records: mask as a segmentation image, field as an image, its own stage list
    out = tmp_path / "b.rrd"
    record(_scene(), out, RecordOptions(tracker="test-bright", level="particles"), progress=False)
    rec = read_rrd(out)
    assert "/video/bright/mask" in rec and "/video/bright/grey" in rec
    assert "/video/detections" not in rec
    assert any("SegmentationImage" in k for _, c in rec["/video/bright/mask"] for k in c)


def test_any_exception_leaves_incomplete_outputs_and_says_why(tmp_path, capsys):
    from pfscope.viewer_app.cli import main

    out, tracks = tmp_path / "x.rrd", tmp_path / "t.txt"
    out.write_bytes(b"previous good recording")
    tracks.write_text("previous good tracks\n")
    rc = main(["record", "synthetic", "--frames", "10", "--tracker", "test-bright",
               "--set", "fail_at=4", "--out", str(out), "--tracks-out", str(tracks), "--force",
               "--quiet"])
    err = capsys.readouterr().err
    assert rc == 1 and "RuntimeError: simulated bug" in err and "Traceback" not in err
    assert err.count("\n") == 1
    # the previous good files are untouched; the partial ones cannot be mistaken for complete
    assert out.read_bytes() == b"previous good recording"
    assert tracks.read_text() == "previous good tracks\n"
    partial = tmp_path / "x.incomplete.rrd"
    assert (tmp_path / "t.incomplete.txt").exists()
    rec = read_rrd(partial)
    assert sorted({t["frame"] for t, _ in rec["/video"]}) == [1, 2, 3]
    last = [c["TextLog:text"] for _, c in rec["/log"]][-1]
    assert "failed at frame 4" in str(last) and "simulated bug" in str(last)


def test_hooks_all_end_even_when_the_tracker_fails(tmp_path):
    ended = []

    class H(BaseHook):
        def end(self, outcome):
            ended.append(outcome)

    tracks = tmp_path / "t.txt"
    writer = TracksFileHook(tracks)
    with pytest.raises(RuntimeError, match="simulated"):
        run(_scene(), [make_tracker("test-bright", fail_at=3)], hooks=[writer, H()])
    assert ended[0].status == "failed" and ended[0].frames == 2
    assert not tracks.exists() and writer.kept_as.exists()


# ----------------------------------------------------------------------------- compare: two stage
# lists on one stage timeline

def test_compare_keeps_each_trackers_stages_in_order_and_frames_apart(tmp_path):
    out = tmp_path / "c.rrd"
    record(_scene(), out, RecordOptions(level="particles"), trackers=["phd", "mt", "test-bright"],
           progress=False)
    rec = read_rrd(out)
    slots = {}
    for ent, rows in rec.items():
        for t, _ in rows:
            if "stage" in t and "frame" in t:
                slots.setdefault(t["frame"], []).append((t["stage"], ent))
    frames = sorted(slots)
    assert len(frames) == 12
    for a, b in zip(frames, frames[1:]):  # frames never overlap on the stage timeline
        assert max(s for s, _ in slots[a]) < min(s for s, _ in slots[b])
    f = frames[6]
    by_ent = {}
    for s, ent in slots[f]:
        by_ent.setdefault(ent, []).append(s)

    def at(ent):
        return min(by_ent[ent])

    # phd's own order, then mt's, then the test tracker's, each followed by its output
    assert at("/phd/video/phd/particles/predicted") < at("/phd/video/phd/particles/updated") \
        < at("/phd/video/phd/clusters/members") < at("/phd/video/assoc/vertices") \
        < at("/phd/video/tracks") < at("/mt/video/assoc/vertices") < at("/mt/video/tracks") \
        < at("/test-bright/video/bright/mask") < at("/test-bright/video/bright/grey") \
        < at("/test-bright/video/tracks")
    assert at("/video") < at("/phd/video/phd/particles/predicted")


def test_set_options_route_per_tracker_in_compare(tmp_path, capsys):
    from pfscope.viewer_app.cli import main

    rc = main(["compare", "synthetic", "--frames", "3", "--trackers", "phd,mt",
               "--set", "phd.p_miss=0.3", "--set", "depth=20", "--preset", "paper",
               "--out", str(tmp_path / "c.rrd"), "--quiet", "--json"])
    assert rc == 0
    rc = main(["record", "synthetic", "--frames", "3", "--set", "p_mis=0.3",
               "--out", str(tmp_path / "d.rrd"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "unknown parameter 'p_mis' (did you mean 'p_miss'?)" in err


def test_trackers_command_lists_papers_stages_and_parameters(capsys):
    from pfscope.viewer_app.cli import main

    assert main(["trackers"]) == 0
    out = capsys.readouterr().out
    for needle in ("phd", "maggio2007", "predict → birth → update", "filter.likelihood.p_miss",
                   "0.05", "mt", "passthrough"):
        assert needle in out, needle


def test_registering_a_clashing_name_fails():
    with pytest.raises(ValueError, match="already registered"):
        @register
        class Other(BrightBlobTracker):
            name = "test-bright"
