"""``pfscope tune``: the app side -- the Rerun recording of a study and its markdown summary.
The search itself (search space, trials, scoring, the study) is the engine's
:mod:`pfscope.trackers.search`; its names are re-exported here.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Optional

from pfscope.trackers.search import *  # noqa: F401,F403 - the search, re-exported
from pfscope.trackers.search import (METRICS, TuneResult, _fmt_opts, _targets,  # noqa: F401
                                     format_table)

# ------------------------------------------------------------------ the study recording

class StudyRecorder:
    """The study as a Rerun recording: on the ``trial`` timeline ``tune/objective`` (each
    trial's score), ``tune/best`` (the best so far) and ``tune/params/<name>`` (each sampled
    value), ``log`` (a line per trial); at the end ``about`` (the table) and the properties
    ``tune`` and ``best``.  Written as ``x.incomplete.rrd`` and renamed when the study ends."""

    def __init__(self, out: Path, title: str, config: dict):
        import rerun as rr
        import rerun.blueprint as rrb
        from datetime import timedelta

        from pfscope.trackers.outputs import incomplete_path

        from .properties import any_values
        from .recorder import recording_id_for

        self.rr = rr
        self.out = Path(out)
        self.partial = incomplete_path(self.out)
        batcher = rr.ChunkBatcherConfig(flush_tick=timedelta(days=1), flush_num_bytes=2 << 20)
        self.rec = rr.RecordingStream("pfscope", recording_id=recording_id_for(
            {"tune": repr(sorted(config.items()))}), send_properties=False,
            batcher_config=batcher)
        bp = rrb.Blueprint(
            rrb.Horizontal(
                rrb.Vertical(
                    rrb.TimeSeriesView(origin="tune", contents=["tune/objective", "tune/best"],
                                       name="Objective per trial"),
                    rrb.TimeSeriesView(origin="tune/params", name="Parameters per trial")),
                rrb.Tabs(rrb.TextDocumentView(origin="about", name="Result"),
                         rrb.TextLogView(origin="log", name="Trials")),
                column_shares=[3, 2]),
            rrb.TimePanel(state="expanded"))
        if self.partial.exists():
            self.partial.unlink()
        self.rec.save(str(self.partial), default_blueprint=bp)
        self.rec.send_recording_name(title)
        self.rec.send_property("tune", any_values(config))
        self.rec.log("tune/objective", rr.SeriesLines(names="objective", colors=[[31, 119, 180]]),
                     static=True)
        self.rec.log("tune/best", rr.SeriesLines(names="best so far", colors=[[44, 160, 44]]),
                     static=True)
        self.rec.log("about", rr.TextDocument(f"# {title}\n\nstudy running…",
                                              media_type=rr.MediaType.MARKDOWN), static=True)

    def trial(self, rec: dict, best: Optional[dict]) -> None:
        rr = self.rr
        self.rec.set_time("trial", sequence=rec["number"])
        if rec["value"] is not None:
            self.rec.log("tune/objective", rr.Scalars(rec["value"]))
        if best is not None:
            self.rec.log("tune/best", rr.Scalars(best["value"]))
        for label, x in rec["params"].items():
            safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", label)
            self.rec.log(f"tune/params/{safe}", rr.Scalars(float(x)))
        what = f"{rec['value']:.4f}" if rec["value"] is not None else f"failed: {rec['error']}"
        self.rec.log("log", rr.TextLog(f"trial {rec['number']}: {what}  "
                                       f"{_fmt_opts(rec['options'])}",
                                       level="INFO" if rec["value"] is not None else "WARN"))

    def finish(self, text: str, best: dict, completed: bool = True) -> Path:
        from .properties import any_values

        self.rec.log("about", self.rr.TextDocument(text, media_type=self.rr.MediaType.MARKDOWN),
                     static=True)
        if best:
            self.rec.send_property("best", any_values(best))
        self.rec.flush()
        self.rec.disconnect()
        if completed:
            os.replace(self.partial, self.out)
            return self.out
        return self.partial

    def abort(self) -> Path:
        try:
            self.rec.log("log", self.rr.TextLog("study stopped before the end", level="WARN"))
            self.rec.flush()
            self.rec.disconnect()
        except Exception:  # noqa: BLE001 - keep what was written
            pass
        return self.partial


def markdown_summary(result: TuneResult, title: str, params_file: Optional[Path]) -> str:
    lines = [f"# {title}", "",
             f"{len(result.trials)} trials, objective {METRICS[result.config.metric]} on the "
             f"tuned-on frames {result.config.frames[0]}-{result.config.frames[1]}; best: "
             f"trial {result.best['number']} ({result.best_value:.4f}; starting values "
             f"{result.start_value:.4f}).", ""]
    if params_file:
        lines += [f"Parameters: `{params_file}` — `pfscope record SOURCE --params "
                  f"{params_file}`.", ""]
    lines += ["```", format_table(result), "```", "", "Searched:", ""]
    lines += [f"- {d.describe()}" for d in result.dims]
    return "\n".join(lines)


__all__ = ["StudyRecorder", "markdown_summary"]
