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


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


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


def select_tab(bp: dict, tab: str) -> dict:
    """The blueprint with the view titled ``tab`` (case-insensitive) active in its tab group."""
    views = _view_names(bp)
    match = [k for k, n in views.items() if n.lower() == tab.lower()]
    if not match:
        raise InputError(f"no tab {tab!r}; the recording's tabs: "
                         f"{', '.join(sorted(set(views.values())))}")
    view = match[0]
    found = False
    for key, val in bp.items():
        cb = val.get("ContainerBlueprint") if isinstance(val, dict) else None
        contents = cb.get("contents") or [] if cb else []
        # contents name views with or without the leading "/"
        hits = [c for c in contents if c.lstrip("/") == view.lstrip("/")]
        if cb and cb.get("container_kind") == "Tabs" and hits:
            cb["active_tab"] = hits[0]
            found = True
    if not found:
        raise InputError(f"tab {tab!r} is not inside a tab group")
    return bp


def _collapse_panels(bp: dict) -> dict:
    for panel in ("/blueprint_panel", "/selection_panel", "/time_panel"):
        entry = bp.setdefault(panel, {})
        key = "TimePanelBlueprint" if panel == "/time_panel" else "PanelBlueprint"
        entry.setdefault(key, {})["state"] = "Collapsed"
    return bp


def snapshot(rrd, out, *, frame: Optional[int] = None, tab: Optional[str] = None,
             clean: bool = True, settle: float = 1.5, timeout: float = 60.0) -> Path:
    """Render ``rrd`` at ``frame`` (default: the last) into the PNG ``out``."""
    from .run import check_output
    from pfscope.trackers.outputs import incomplete_path

    rrd, out = Path(rrd), Path(out)
    if not rrd.is_file():
        raise InputError(f"{rrd}: no such recording")
    from .info import check_rrd_header

    check_rrd_header(rrd)
    out = check_output(out, force=True, what="picture")
    problem = vulkan_problem()
    if problem:
        raise RunFailed(problem)
    from rerun.experimental import ViewerClient

    port = _free_port()
    try:
        viewer = ViewerClient.spawn(headless=True, port=port, hide_welcome_screen=True)
    except Exception as e:  # noqa: BLE001 - one line for any start failure
        raise RunFailed(f"the headless viewer did not start ({type(e).__name__}: {e}); "
                        f"{VULKAN_HINT}") from None
    try:
        try:
            viewer.open(str(rrd.resolve()))
        except Exception as e:  # noqa: BLE001
            raise RunFailed(f"the headless viewer could not open {rrd} or did not start "
                            f"({type(e).__name__}: {str(e)[:200]}); {VULKAN_HINT}") from None
        try:
            if tab or clean:
                info = viewer.get_blueprint()
                bp = info.blueprint
                if tab:
                    bp = select_tab(bp, tab)
                if clean:
                    bp = _collapse_panels(bp)
                viewer.set_blueprint(bp, store_id=info.store_id)
            if frame is not None:
                viewer.set_time("frame", sequence=int(frame), play_state="paused")
            else:
                viewer.set_time(play_state="paused")
            time.sleep(settle)  # let the frame's chunks load and the views lay out
            tmp = incomplete_path(out)
            viewer.save_screenshot(str(tmp))
            os.replace(tmp, out)
        except InputError:
            raise
        except Exception as e:  # noqa: BLE001 - a truncated or foreign file: one line
            raise RunFailed(f"{rrd}: the viewer could not show it ({type(e).__name__}: "
                            f"{str(e).splitlines()[0][:200] if str(e) else ''})") from None
    finally:
        try:
            viewer.quit(timeout=10)
        except Exception:  # noqa: BLE001 - teardown best effort
            pass
    return out


def cmd_snapshot(args) -> int:
    out = snapshot(args.file, args.out, frame=args.frame, tab=args.tab,
                   clean=not args.keep_panels)
    print(f"wrote {out}")
    return 0


__all__ = ["snapshot", "select_tab", "tab_names", "vulkan_problem", "cmd_snapshot"]
