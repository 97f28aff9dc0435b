"""What a recording says about itself: typed recording properties, the "About" note, and
reading both back (``pfscope info``).

Properties (Rerun's recording properties, ``/__properties/<group>``), each an ``AnyValues`` of
typed fields, nested dicts flattened to dotted names:

- ``run``: trackers (lanes), detector, level, max_points, first_frame, frames, seed, preset;
- ``source``: the source's ``describe()`` (kind, name, location, fps, length, size, scene.* ...);
- ``tracker.<lane>``: the lane's tracker name, preset and every parameter
  (``params.filter.likelihood.p_miss`` ...);
- ``versions``: pfscope, rerun-sdk, numpy, scipy, opencv, numba, llvmlite, torch, python;
- ``scores.<lane>``: the sequence scores (MOTA, IDF1, HOTA, OSPA ...), written when the run ends;
- ``events.<lane>``: how many of each event the failure index holds.

The "About" note is a static markdown ``TextDocument`` at ``about``.
"""

from __future__ import annotations

import math
from typing import Any, Iterable, Optional

import numpy as np

PROPERTY_ROOT = "/__properties"


def flatten(d: dict, prefix: str = "") -> dict[str, Any]:
    """``{"a": {"b": 1}}`` → ``{"a.b": 1}``; values become typed scalars or numeric arrays
    (None and NaN are dropped, anything else becomes its string)."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, name + "."))
        elif v is None:
            continue
        elif isinstance(v, (bool, np.bool_)):
            out[name] = bool(v)
        elif isinstance(v, (int, np.integer)):
            out[name] = int(v)
        elif isinstance(v, (float, np.floating)):
            if not math.isnan(v):  # NaN (a score with nothing to average) is left out: it
                out[name] = float(v)  # never compares equal, same-seed files would differ
        elif isinstance(v, str):
            out[name] = v
        elif isinstance(v, (list, tuple, np.ndarray)) and len(v) and all(
                isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, bool)
                for x in v):
            out[name] = np.asarray(v, dtype=np.float64)
        elif isinstance(v, (list, tuple)) and len(v) and all(isinstance(x, str) for x in v):
            out[name] = ", ".join(v)
        else:
            out[name] = str(v)
    return out


def any_values(d: dict):
    import rerun as rr

    return rr.AnyValues(**flatten(d))


def about_markdown(title: str, views: Iterable[tuple[str, Iterable[str]]],
                   plots: Iterable[tuple[str, Iterable[str]]], *, lanes: Iterable[str] = (),
                   has_gt: bool = False) -> str:
    """A short note on what each tab shows (the tabs come from the tracker's layout)."""
    lines = [f"# {title}", "",
             "Recorded by **pfscope**. Timelines: **frame** (the video frame), **time** (the "
             "video's clock), **stage** (steps through the stages inside one frame). "
             "Run `pfscope info FILE.rrd` for the source, parameters, versions and scores.", ""]
    lanes = list(lanes)
    if lanes:
        lines += ["## Lanes", "", "Each lane is one tracker (or one parameter variant) under its "
                  "own root: " + ", ".join(f"`/{n}`" for n in lanes) + ". The video, detections "
                  "and ground truth are shared.", ""]
    lines += ["## Video tabs", ""]
    for title_, paths in views:
        shown = ", ".join(f"`{p}`" for p in paths)
        lines.append(f"- **{title_}**: the frame with {shown}.")
    lines.append("- **All stages**: every entity of the frame at once.")
    lines += ["", "## Plots", ""]
    for title_, paths in plots:
        lines.append(f"- **{title_}**: " + ", ".join(f"`{p}`" for p in paths) + ".")
    if has_gt and not lanes:
        lines += ["- **Metrics**: per frame, the true vs estimated count, false positives, misses "
                  "and ID switches; **OSPA**: the per-frame OSPA distance (px)."]
    lines += ["- **All series**: every series of the recording.", "",
              "## Colours", "",
              "- Tracks: one colour per track id, the same on its box, trail, vertices, edges, "
              "clusters and child clouds, chosen in OKLab so that ids alive at the same time "
              "are far apart; no track colour is near red, magenta, cyan, pink, viridis yellow, "
              "grey, white or black (those are marks). Labelled with the id, with a trail of "
              "recent centres (a trail restarts where its track jumps).",
              "- Items with no identity (classifier windows, candidates, candidate edges): thin "
              "grey.",
              "- Detections: thin grey boxes (scores in the hidden labels: select the entity "
              "and turn labels on). Ground truth: thin white boxes (gt ids hidden the same way).",
              "- Misses: red. False positives: magenta, drawn 4 px outside the track box. "
              "ID switches: thick black, 8 px outside. Marks are drawn over the track boxes. "
              "These never occur in the track palette.",
              "- Births: newborn particles are pink dots (the survivors keep their weight "
              "colours). Classifier hits (DLPF windows, DBN-accepted blobs): cyan boxes (the "
              "rejected windows stay thin grey).",
              "- Clusters: a kept cluster (its box and members) in the colour of the confirmed "
              "track that took it; a kept cluster no confirmed track took in light grey; a "
              "dropped cluster dark grey.",
              "- Association: this frame's vertices as thin boxes in their track's colour "
              "(tentative tracks too), the chosen edges in the track's colour labelled "
              "`id: gap=… log f=…` (the edge gain), candidate edges thin grey.",
              "- Particles: colour = the particle's weight *ranked within its cloud* (each "
              "cloud, each frame), on viridis: dark purple = the lightest, teal = the median, "
              "yellow = the heaviest tenth. Heavier particles are also larger, more opaque and "
              "drawn on top. A cloud of equal weights (predicted, resampled, DLPF's free "
              "parents) is all teal. "
              "Ranks hide how uneven the weights are: `plots/weights/<cloud>/top_tenth` is the "
              "share of the cloud's weight its yellow tenth holds (0.1 = even, near 1 = a few "
              "particles carry it all) and `.../ess` its effective sample size / N.",
              "- A per-particle score (DBN-PHD's DBN score tab) is on viridis by its value, "
              "0 (purple) to 1 (yellow), not by rank. A dense field (DLPF's motion) is viridis "
              "from 0 (transparent) to the frame's largest value, plotted as `.../max`.",
              "- Plots: misses red, false positives magenta, true count white, as on the video"
              + ("; in the lane plots each lane has its own colour." if lanes else "."),
              ""]
    if has_gt:
        lines += ["## Events", "",
                  "The **Events** log indexes every ID switch, false track, lost track and long "
                  "miss, and the worst frames by OSPA; click a row to jump to its frame.", ""]
    return "\n".join(lines)


# ------------------------------------------------------------------------------ reading back

def read_properties(path, note: bool = True) -> dict[str, dict]:
    """``{group: {field: value}}`` of a recording's properties (single values unwrapped).  A
    file without footer is streamed; one torn inside an entry (a killed run) is read up to its
    last whole entry, saying so in one line on stderr when ``note``."""
    from .rrdfile import open_chunks

    chunks, _, _ = open_chunks(path, note=note)
    out: dict[str, dict] = {}
    for ch in chunks:
        ent = ch.entity_path
        if not ent.startswith(PROPERTY_ROOT):
            continue
        group = ent[len(PROPERTY_ROOT):].lstrip("/").replace("\\", "") or "recording"
        rb = ch.to_record_batch()
        for name in rb.schema.names:
            if name in ("log_time", "rerun.controls.RowId") or name in ch.timeline_names:
                continue
            vals = rb.column(name).to_pylist()
            v = vals[-1] if vals else None
            if isinstance(v, list) and len(v) == 1:
                v = v[0]
            out.setdefault(group, {})[name.split(":")[-1] if group == "recording" else name] = v
    return out


def _num(v) -> Optional[float]:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


__all__ = ["flatten", "any_values", "about_markdown", "read_properties", "PROPERTY_ROOT"]
