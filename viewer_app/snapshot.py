"""``pfscope snapshot FILE.rrd --frame N [--tab NAME] --out shot.png``: a picture of a recording
at one frame, rendered by Rerun's headless viewer (``rerun.experimental.ViewerClient``).

The headless viewer renders with Vulkan; on a machine without a GPU it needs Mesa's software
driver (Debian/Ubuntu: ``apt-get install mesa-vulkan-drivers libvulkan1``).  Without it the
command ends with one line saying so.

``--tab`` picks a video tab by its title (``Particles``, ``Association`` ...: the tracker's
layout, see the recording's About note); the blueprint stored in the file is changed in the
viewer only (the file is never modified).  ``--clean`` (the default) collapses the side panels
so the picture is the views themselves.
"""

from __future__ import annotations

import ctypes.util
import glob
import os
import socket
import time
from pathlib import Path
from typing import Optional

from pfscope.trackers.errors import InputError, RunFailed

VULKAN_HINT = ("the headless viewer needs Vulkan (on a machine without a GPU: "
               "apt-get install mesa-vulkan-drivers libvulkan1)")


def vulkan_problem() -> Optional[str]:
    """Why the headless viewer cannot start here, or None when it probably can."""
    if ctypes.util.find_library("vulkan") is None and not glob.glob(
            "/usr/lib/*/libvulkan.so*") and not glob.glob("/usr/lib/libvulkan.so*"):
        return f"no Vulkan loader (libvulkan) found: {VULKAN_HINT}"
    if os.name == "posix" and os.uname().sysname == "Linux":
        icds = [p for d in ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d",
                            "/usr/local/share/vulkan/icd.d") for p in glob.glob(f"{d}/*.json")]
        if not icds and not os.environ.get("VK_ICD_FILENAMES") and not os.environ.get(
                "VK_DRIVER_FILES"):
            return f"no Vulkan driver (ICD) found: {VULKAN_HINT}"
    return None


def _view_names(bp: dict) -> dict[str, str]:
    """view entity path -> display name; the video (2D) views first, so a title shared by a
    video tab and a plot ("Particles") picks the video tab."""
    views = []
    for key, val in bp.items():
        vb = val.get("ViewBlueprint") if isinstance(val, dict) else None
        if vb and key.startswith("/view/") and key.count("/") == 2:
            views.append((vb.get("class_identifier") != "2D", key, vb.get("display_name", "")))
    return {key: name for _, key, name in sorted(views, key=lambda v: v[0])}


def tab_names(bp: dict) -> list[str]:
    return sorted(set(_view_names(bp).values()))


def _tab_children(bp: dict) -> list[tuple[str, str, str]]:
    """(tabs container key, child key, title) of every child of a Tabs container that is a 2D
    view or a container of 2D views (compare: a stage's grid of lane views)."""
    def entry(key):
        return bp.get("/" + key.lstrip("/")) or {}

    def is_2d(key):
        vb = entry(key).get("ViewBlueprint")
        if vb:
            return vb.get("class_identifier") == "2D"
        cb = entry(key).get("ContainerBlueprint")
        return bool(cb) and bool(cb.get("contents")) and all(is_2d(c) for c in cb["contents"])

    out = []
    for key, val in bp.items():
        cb = val.get("ContainerBlueprint") if isinstance(val, dict) else None
        if not cb or cb.get("container_kind") != "Tabs":
            continue
        for c in cb.get("contents") or []:
            if is_2d(c):
                e = entry(c)
                title = (e.get("ViewBlueprint") or e.get("ContainerBlueprint") or {}).get(
                    "display_name", "")
                out.append((key, c, title))
    return out


def select_tab(bp: dict, tab: str) -> dict:
    """The blueprint with the video tab titled ``tab`` (case-insensitive: a 2D view, or in a
    compare recording a stage's grid of lanes) active in its tab group."""
    kids = _tab_children(bp)
    match = [(k, c) for k, c, t in kids if t.lower() == tab.lower()]
    if not match:
        raise InputError(f"no tab {tab!r}; the recording's tabs: "
                         f"{', '.join(dict.fromkeys(t for _, _, t in kids))}")
    for key, child in match:
        bp[key]["ContainerBlueprint"]["active_tab"] = child
    return bp


def _collapse_panels(bp: dict) -> dict:
    for panel in ("/blueprint_panel", "/selection_panel", "/time_panel"):
        entry = bp.setdefault(panel, {})
        key = "TimePanelBlueprint" if panel == "/time_panel" else "PanelBlueprint"
        entry.setdefault(key, {})["state"] = "Collapsed"
    return bp


def _collapse_top(bp: dict) -> dict:
    """The top bar (its "software rasterizer" warning) collapsed too."""
    bp.setdefault("/top_panel", {}).setdefault("PanelBlueprint", {})["state"] = "Collapsed"
    return bp


def stage_slots(rrd: Path) -> tuple[int, dict[str, int]]:
    """(slots per frame, stage name -> its slot within a frame) of a recording, from its run
    properties and the trackers' declared stage lists (the recorder's layout: ``input``, then
    each lane's stages and its ``output``).  In a compare recording a stage name is
    ``LANE:STAGE`` (a bare name picks the first lane that has it)."""
    from pfscope.trackers.api import registry

    from .properties import read_properties

    props = read_properties(rrd)
    lanes = {g.split(".", 1)[1]: v for g, v in props.items() if g.startswith("tracker.")}
    order = (props.get("run") or {}).get("lanes") or list(lanes)
    if isinstance(order, str):
        order = [x.strip() for x in order.split(",")]
    reg = registry()
    slots: dict[str, int] = {"input": 0}
    n = 1
    for lane in order:
        name = (lanes.get(lane) or {}).get("tracker", lane)
        cls = reg.get(name)
        if cls is None:
            raise InputError(f"{rrd}: tracker {name!r} of lane {lane!r} is not known here")
        for st in tuple(cls.stages) + ("output",):
            slots[f"{lane}:{st}"] = n
            slots.setdefault(st, n)
            n += 1
    return n, slots


class _Viewer:
    """Rerun's headless viewer, started by us: listening on 127.0.0.1 only, its logs (Rust
    tracing with terminal colours) kept in a file instead of our stderr (shown, last lines
    only, when it fails), bounded waits."""

    def __init__(self, timeout: float):
        import tempfile

        from rerun.experimental import ViewerClient

        from .serve import free_port, rerun_binary, spawn

        self.port = free_port()
        self.log = tempfile.NamedTemporaryFile(prefix="pfscope-viewer-", suffix=".log",
                                               delete=False)
        env = {**os.environ, "RERUN_APP_ONLY": "true", "RERUN_ANALYTICS": "0",
               "NO_COLOR": "1", "RUST_LOG": os.environ.get("PFSCOPE_VIEWER_LOG", "warn")}
        cmd = rerun_binary() + ["--headless", "--bind", "127.0.0.1", "--port", str(self.port),
                                  "--hide-welcome-screen", "--memory-limit", "75%"]
        try:
            # its own process group, ended as one, and ended with us
            self.proc = spawn(cmd, self.log, env)
        except OSError as e:
            raise RunFailed(f"the headless viewer did not start ({e}); {VULKAN_HINT}") from None
        url = f"rerun+http://127.0.0.1:{self.port}/proxy"
        deadline = time.monotonic() + timeout
        last: Optional[Exception] = None
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                self.close()
                raise RunFailed(f"the headless viewer exited ({self.tail()}); {VULKAN_HINT}")
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.5):
                    pass
                self.client = ViewerClient(url)
                return
            except Exception as e:  # noqa: BLE001 - not listening yet
                last = e
                time.sleep(0.2)
        self.close()
        raise RunFailed(f"the headless viewer did not answer within {timeout:.0f} s "
                        f"({type(last).__name__ if last else 'no reply'}); {VULKAN_HINT}")

    def tail(self) -> str:
        from .serve import log_tail

        return log_tail(self.log.name)

    def close(self) -> None:
        from .serve import end_group

        end_group(self.proc)
        self.log.close()
        try:
            os.unlink(self.log.name)
        except OSError:
            pass


def series_path(out: Path, frame: int) -> Path:
    """``shot.png`` -> ``shot-000080.png`` (one picture per frame of a ``--frames`` series)."""
    return out.with_name(f"{out.stem}-{frame:06d}{out.suffix or '.png'}")


def snapshot(rrd, out, *, frame: Optional[int] = None, tab: Optional[str] = None,
             clean: bool = True, settle: float = 1.5, timeout: float = 60.0,
             stage: Optional[str] = None, frames: Optional[tuple[int, int]] = None):
    """Render ``rrd`` at ``frame`` (default: the last) into the PNG ``out``.  ``stage``: at that
    stage of the frame (the ``stage`` timeline: what the frame's earlier stages logged);
    ``frames=(a, b)``: one picture per frame, ``out`` numbered (:func:`series_path`); returns
    the path, or the list of paths for a series."""
    from .run import check_output
    from pfscope.trackers.outputs import incomplete_path

    rrd, out = Path(rrd), Path(out)
    if not rrd.is_file():
        raise InputError(f"{rrd}: no such recording")
    from .info import check_readable

    check_readable(rrd)   # its header, then every chunk: before the viewer starts
    wanted = list(range(frames[0], frames[1] + 1)) if frames else [frame]
    outs = [series_path(out, f) for f in wanted] if frames else [out]
    for o in outs:
        check_output(o, force=True, what="picture")
    slot = None
    if stage is not None:
        stride, slots = stage_slots(rrd)
        if stage not in slots:
            raise InputError(f"no stage {stage!r}; the recording's stages: "
                             f"{', '.join(slots)}")
        slot = slots[stage]
    problem = vulkan_problem()
    if problem:
        raise RunFailed(problem)
    from .rrdfile import release, scan, trimmed_copy

    # the viewer refuses a file torn inside an entry (a killed run): it gets the whole entries
    # (a temporary copy; check_readable said so in one line)
    layout = scan(rrd)
    shown_file = trimmed_copy(rrd, layout.whole) if layout.torn else None
    try:
        viewer = _Viewer(timeout)
    except BaseException:
        release(shown_file)
        raise
    try:
        client = viewer.client
        try:
            client.open(shown_file or str(rrd.resolve()))
        except Exception as e:  # noqa: BLE001
            raise RunFailed(f"the headless viewer could not open {rrd} "
                            f"({type(e).__name__}: {str(e)[:200]}); {VULKAN_HINT}") from None
        try:
            info = client.get_blueprint()
            if tab and tab.lower() == "all":  # every video tab, one picture each
                titles = video_tabs(info.blueprint)
                jobs = [(t, f, tab_path(o, t)) for t in titles for f, o in zip(wanted, outs)]
            else:
                jobs = [(tab or ("All stages" if stage else None), f, o)
                        for f, o in zip(wanted, outs)]
            shown = object()
            for t, f, o in jobs:
                if t != shown and (t or clean):
                    bp = info.blueprint
                    if t:
                        bp = select_tab(bp, t)
                    if clean:
                        bp = _collapse_top(_collapse_panels(bp))
                    client.set_blueprint(bp, store_id=info.store_id)
                    shown = t
                    settle = max(settle, 1.0)
                if slot is not None:
                    last = f if f is not None else _last_frame(rrd)
                    client.set_time("stage", sequence=int(last) * stride + slot,
                                    play_state="paused")
                elif f is not None:
                    client.set_time("frame", sequence=int(f), play_state="paused")
                else:
                    client.set_time(play_state="paused")
                time.sleep(settle)  # let the frame's chunks load, the views lay out, toasts fade
                tmp = incomplete_path(o)
                for attempt in (1, 2):  # a busy machine can miss the viewer's deadline once
                    try:
                        client.save_screenshot(str(tmp))
                        break
                    except Exception as e:  # noqa: BLE001 - one line, never a traceback
                        if attempt == 2:
                            raise RunFailed(f"the headless viewer did not take the picture "
                                            f"{o.name} ({type(e).__name__}: {str(e)[:120]})"
                                            ) from None
                        time.sleep(settle)
                os.replace(tmp, o)
                settle = min(settle, 0.8)  # the next frames of a series: the data is loaded
        except (InputError, RunFailed):
            raise
        except Exception as e:  # noqa: BLE001 - a truncated or foreign file: one line
            raise RunFailed(f"{rrd}: the viewer could not show it ({type(e).__name__}: "
                            f"{str(e).splitlines()[0][:200] if str(e) else ''})") from None
    finally:
        viewer.close()
        release(shown_file)
    if len(jobs) > 1:
        return [o for _, _, o in jobs]
    return outs if frames else outs[0]


def video_tabs(bp: dict) -> list[str]:
    """The titles of the blueprint's video tabs, in their tab order."""
    return list(dict.fromkeys(t for _, _, t in _tab_children(bp)))


def tab_path(out: Path, title: str) -> Path:
    """``shot.png`` + "Birth & update" -> ``shot-birth-update.png``."""
    import re

    slug = re.sub(r"[^a-z0-9]+", "-", title.lower()).strip("-") or "tab"
    return out.with_name(f"{out.stem}-{slug}{out.suffix or '.png'}")


def _last_frame(rrd: Path) -> int:
    from .info import recording_info

    last = recording_info(rrd)["frames"]["last"]
    if last is None:
        raise InputError(f"{rrd}: no recorded frames")
    return int(last)


def cmd_snapshot(args) -> int:
    if args.frames and args.frame:
        raise InputError("give --frame N or --frames A:B, not both")
    got = snapshot(args.file, args.out, frame=args.frame, tab=args.tab,  # "all": every tab
                   clean=not args.keep_panels, stage=args.stage, frames=args.frames)
    if isinstance(got, list):
        print(f"wrote {len(got)} pictures: {got[0]} .. {got[-1]}")
    else:
        print(f"wrote {got}")
    return 0


__all__ = ["snapshot", "select_tab", "tab_names", "vulkan_problem", "cmd_snapshot",
           "stage_slots", "series_path"]
