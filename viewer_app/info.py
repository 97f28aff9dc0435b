"""``pfscope info FILE.rrd``: what a recording is, read from the file alone (its properties, its
entities, its frames, its failure index); and ``pfscope view FILE.rrd``.

Reads with ``rr.chunk.RrdReader``; a file left without its footer (a killed run) is streamed, one
torn inside an entry is read up to its last whole entry (:mod:`.rrdfile`).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

from pfscope.trackers.errors import InputError

from .properties import PROPERTY_ROOT, read_properties
from .rrdfile import cut_note
from .tabs import from_property as tabs_from_property

#: The scores ``info`` prints (all of them are in ``--json``).
HEADLINE = ("MOTA", "MOTP", "IDF1", "HOTA", "IDSW", "FP", "FN", "OSPA")


RRD_MAGIC = b"RRF2"


def check_rrd_header(path: Path) -> None:
    """One line when ``path`` is not a Rerun recording (empty, or not starting with RRF2)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(len(RRD_MAGIC))
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror or e})") from None
    if not head:
        raise InputError(f"{path}: empty file, not a Rerun recording")
    if head != RRD_MAGIC:
        raise InputError(f"{path}: not a Rerun recording (it does not start with "
                         f"{RRD_MAGIC.decode()})")


def _open(path: Path, note: bool = True):
    """``(chunks, footer)``; a torn file (a killed run) is read up to its last whole entry, with
    one line on stderr when ``note`` (:func:`pfscope.viewer_app.rrdfile.open_chunks`)."""
    chunks, footer, _ = _open_layout(path, note)
    return chunks, footer


def _open_layout(path: Path, note: bool = True):
    from .rrdfile import open_chunks

    if not path.is_file():
        raise InputError(f"{path}: no such recording")
    check_rrd_header(path)
    return open_chunks(path, note=note)


def check_readable(path) -> None:
    """Read every chunk of the recording once: an :class:`InputError` (one line) for a file
    that is cut short, holds no data or is not a recording, before anything slower (the
    headless viewer of ``snapshot``) is started on it."""
    path = Path(path)
    chunks, _ = _open(path)
    n = 0
    for _ in chunks:   # an InputError (one line) when it cannot be read
        n += 1
    if n == 0:
        raise InputError(f"{path}: holds no recorded data")


def recording_info(path, top: int = 10) -> dict[str, Any]:
    """Everything ``pfscope info`` shows, as a plain dict (``--json`` prints it)."""
    import pyarrow as pa

    path = Path(path)
    chunks, footer, layout = _open_layout(path, note=False)   # the header line says it
    entities: set[str] = set()
    frames: set[int] = set()
    times: list[int] = []
    events: dict[str, list] = {}
    worst: dict[str, list] = {}
    last_log = None
    try:
        for ch in chunks:
            ent = ch.entity_path
            if ent.startswith(PROPERTY_ROOT):
                continue
            entities.add(ent)
            is_event = ent.endswith("/events") or ent.endswith("/events/worst_ospa")
            is_video = ent == "/video"
            is_log = ent == "/log"
            if not (is_event or is_video or is_log):
                continue
            rb = ch.to_record_batch()
            names = rb.schema.names
            fr = rb.column("frame").cast(pa.int64()).to_pylist() if "frame" in names else []
            if is_video:
                frames.update(f for f in fr if f is not None)
                if "time" in names:
                    times.extend(t for t in rb.column("time").cast(pa.int64()).to_pylist()
                                 if t is not None)
                continue
            texts = rb.column("TextLog:text").to_pylist() if "TextLog:text" in names else []
            extra = {}
            for key in ("kind", "track_ids", "gt_ids", "message", "last_frame", "level"):
                col = next((n for n in names if n.rsplit(":", 1)[-1] == key), None)
                if col is not None:
                    extra[key] = [v[0] if isinstance(v, list) and v else v
                                  for v in rb.column(col).to_pylist()]
            for i, (f, t) in enumerate(zip(fr, texts)):
                msg = t[0] if isinstance(t, list) and t else t
                more = {k: v[i] for k, v in extra.items() if v[i] is not None}
                if "message" in more:   # the row's body is short; the full sentence is here
                    msg = more.pop("message")
                if is_log:
                    last_log = (f, msg)
                    continue
                if ent.endswith("/worst_ospa"):
                    lane = ent[:-len("/events/worst_ospa")].strip("/") or "-"
                    worst.setdefault(lane, []).append({"frame": f, "message": msg})
                else:
                    lane = ent[:-len("/events")].strip("/") or "-"
                    ev = {"frame": f, "message": msg, **more}
                    for k in ("track_ids", "gt_ids"):
                        if isinstance(ev.get(k), str):
                            # "-": no id (the recorder never logs an empty string)
                            ev[k] = [int(x) for x in ev[k].split() if x != "-"]
                    events.setdefault(lane, []).append(ev)
    except InputError:
        raise
    except Exception as e:  # noqa: BLE001
        raise InputError(f"{path}: unreadable chunk ({type(e).__name__}: {e})") from None
    try:
        props = read_properties(path, note=False)
    except Exception as e:  # noqa: BLE001 - the file's fault
        if isinstance(e, InputError):
            raise
        raise InputError(f"{path}: unreadable properties ({type(e).__name__}: "
                         f"{str(e).splitlines()[0][:160] if str(e) else ''})") from None
    lanes = {g.split(".", 1)[1]: v for g, v in props.items() if g.startswith("tracker.")}
    scores = {g.split(".", 1)[1]: v for g, v in props.items() if g.startswith("scores.")}
    counts = {g.split(".", 1)[1]: v for g, v in props.items() if g.startswith("events.")}
    if len(lanes) == 1:  # one lane: its entities have no root of their own
        only = next(iter(lanes))
        for d in (events, worst):
            if "-" in d:
                d[only] = d.pop("-")
    order = list((props.get("run") or {}).get("lanes") or [])
    if isinstance(order, str):
        order = [x.strip() for x in order.split(",")]

    def ordered(d: dict) -> dict:
        return {k: d[k] for k in sorted(d, key=lambda k: (order.index(k) if k in order
                                                        else len(order), k))}

    lanes, scores, counts = ordered(lanes), ordered(scores), ordered(counts)
    severity = {"ERROR": 0, "WARN": 1, "INFO": 2, "DEBUG": 3}
    for lst in events.values():  # for jumping: the severe first, then by frame
        lst.sort(key=lambda e: (severity.get(str(e.get("level", "INFO")), 2), e["frame"],
                                e["message"]))
    for lst in worst.values():
        lst.sort(key=lambda e: int(e["message"].split("#")[1].split(":")[0])
                 if "#" in e["message"] else 0)
    return {
        "file": str(path), "bytes": path.stat().st_size, "complete": footer,
        # a torn file (the run killed inside an entry): the bytes read, up to its last whole one
        "cut": ({"read_bytes": layout.whole, "note": cut_note(path, layout)}
                if layout is not None and layout.torn else None),
        "name": props.get("recording", {}).get("name"),
        "run": props.get("run", {}), "source": props.get("source", {}),
        "lanes": lanes, "versions": props.get("versions", {}),
        "legacy_config": props.get("config"),
        "frames": {"count": len(frames), "first": min(frames) if frames else None,
                   "last": max(frames) if frames else None},
        "duration_s": (max(times) - min(times)) / 1e9 if len(times) > 1 else 0.0,
        "entities": sorted(entities),
        "tabs": tabs_from_property(props) or [],
        "scores": scores, "event_counts": counts,
        "events": {k: v[:top] for k, v in events.items()},
        "worst_ospa": {k: v[:top] for k, v in worst.items()},
        "ended": last_log[1] if last_log else None,
    }


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return ", ".join(_fmt(x) for x in v)
    return str(v)


def print_info(info: dict, out=None, params: bool = True) -> None:
    out = out or sys.stdout

    def p(s=""):
        print(s, file=out)

    run, src = info["run"], info["source"]
    if info.get("cut"):
        state = (f", cut inside an entry (a killed run?): read its first "
                 f"{info['cut']['read_bytes'] / 1e6:.1f} MB, up to its last whole entry; try "
                 f"pfscope repair")
    else:
        state = "" if info["complete"] else ", no footer: a killed run? try pfscope repair"
    p(f"{info['file']}  ({info['bytes'] / 1e6:.1f} MB{state})")
    if info.get("name"):
        p(f"recording: {info['name']}")
    if src:
        size = f"{src.get('width')}x{src.get('height')}" if src.get("width") else "?"
        p(f"source:    {src.get('name')} ({src.get('kind')}, {src.get('location')}), {size}, "
          f"{_fmt(src.get('fps'))} fps, {src.get('length')} frames, "
          f"gt: {'yes' if src.get('has_gt') else 'no'}, det: {'yes' if src.get('has_det') else 'no'}"
          + (f", pixels: {src['pixels']} (cues that read pixels off)" if src.get("pixels") else ""))
    if run:
        p(f"run:       lanes {_fmt(run.get('lanes'))}; detector {run.get('detector')}; level "
          f"{run.get('level')}; seed {run.get('seed')}; preset {run.get('preset')}; first frame "
          f"{run.get('first_frame')}")
    elif info.get("legacy_config"):
        p(f"config:    {info['legacy_config']}")
    fr = info["frames"]
    p(f"frames:    {fr['count']} ({fr['first']}..{fr['last']}), {info['duration_s']:.1f} s of "
      f"video; {len(info['entities'])} entities")
    if info.get("ended"):
        p(f"ended:     {info['ended']}")
    if info.get("tabs"):
        p("tabs:      " + ", ".join(t["title"] for t in info["tabs"])
          + "  (entities per tab: --json)")
    if info["versions"]:
        p("versions:  " + ", ".join(f"{k} {v}" for k, v in sorted(info["versions"].items())))
    for lane, cfg in info["lanes"].items():
        p()
        p(f"[{lane}] tracker {cfg.get('tracker')}" + (f" ({cfg.get('spec')})"
                                                      if cfg.get("spec") != lane else ""))
        if params:
            for k, v in sorted(cfg.items()):
                if k.startswith("params."):
                    name = k[len("params."):]
                    eff, origin = cfg.get(f"effective.{name}"), cfg.get(f"origin.{name}")
                    line = f"    {name} = {_fmt(v)}"
                    if eff is not None and eff != v:
                        line += f" -> in effect {_fmt(eff)}"
                    if origin:
                        line += f"  ({origin})"
                    p(line)
    if info["scores"]:
        p()
        lanes = list(info["scores"])
        width = max(8, *(len(n) for n in lanes))
        conv = {sc.get("convention") for sc in info["scores"].values()}
        p(f"scores (convention {', '.join(str(c) for c in conv)}):")
        p(f"  {'lane':<{width}} " + " ".join(f"{k:>7}" for k in HEADLINE))
        for lane in lanes:
            sc = info["scores"][lane]
            p(f"  {lane:<{width}} " + " ".join(
                f"{sc.get(k, float('nan')):>7.3f}" if k not in ("IDSW", "FP", "FN")
                else f"{int(sc.get(k, 0)):>7d}" for k in HEADLINE))
    for lane, counts in info["event_counts"].items():
        p()
        p(f"events [{lane}]: " + ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in counts.items()))
        for e in info["events"].get(lane, []):
            p(f"  frame {e['frame']:>5}  {e['message']}")
        ws = info["worst_ospa"].get(lane, [])
        if ws:
            p("  worst frames by OSPA: " + ", ".join(
                f"{e['frame']} ({e['message'].rsplit('OSPA ', 1)[-1]})" for e in ws))
    if not info["event_counts"] and info["source"] and not info["source"].get("has_gt"):
        p("no ground truth: no scores and no failure index")


def cmd_info(args) -> int:
    info = recording_info(args.file, top=args.top)
    if args.json:
        print(json.dumps(info, indent=2, sort_keys=True, default=str))
    else:
        print_info(info, params=not args.no_params)
    return 0


def viewer_command() -> list[str]:
    exe = shutil.which("rerun") or str(Path(sys.executable).with_name("rerun"))
    return [exe]


def cmd_view(args) -> int:
    from .run import display_available

    path = Path(args.file)
    if not path.is_file():
        raise InputError(f"{path}: no such recording")
    from .rrdfile import check_whole_for_viewer

    check_whole_for_viewer(path)   # the viewer refuses a torn file: say what to do instead
    if getattr(args, "web", False):
        from .serve import cmd_view_web

        return cmd_view_web(path, web_port=getattr(args, "web_port", None))
    if not display_available():
        print(f"pfscope view: no display here; serve it to a browser (rerun's web viewer) "
              f"with 'pfscope view {path} --web', or take a picture with "
              f"'pfscope snapshot {path} --frame N --out shot.png'")
        return 0
    cmd = viewer_command() + [os.path.abspath(path)]  # a name may start with '-'
    subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL,
                     stderr=subprocess.DEVNULL, env={**os.environ, "RERUN_ANALYTICS": "0"})
    print(f"opened {path} in the Rerun viewer")
    return 0


__all__ = ["recording_info", "print_info", "cmd_info", "cmd_view"]
