"""Serving a recording to a browser: Rerun's web viewer over HTTP plus a gRPC server holding the
file, both on 127.0.0.1 only (``pfscope view FILE.rrd --web``; ``record --serve`` after its run).

The servers are Rerun's own (``rerun --serve-web`` / ``--serve-grpc``), started as a child in its
own process group with its logs in a file (shown, last line only, when it fails), and ended as
one group on Ctrl-C, SIGTERM or :meth:`WebServer.close`.  Start-up waits are bounded.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import tempfile
import time
import urllib.parse
import urllib.request
from pathlib import Path
from typing import Optional

from pfscope.trackers.errors import InputError, RunFailed

HOST = "127.0.0.1"


def free_port() -> int:
    with socket.socket() as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


def viewer_url(web_port: int, grpc_port: int) -> str:
    """The browser URL of the web viewer connected to the gRPC server."""
    proxy = urllib.parse.quote(f"rerun+http://{HOST}:{grpc_port}/proxy", safe="")
    return f"http://{HOST}:{web_port}/?url={proxy}"


def rerun_binary() -> list[str]:
    """The viewer binary itself when the wheel ships it (``rerun_cli/rerun``: no Python wrapper
    between us and it, so it can be tied to our lifetime), else ``rerun`` on PATH."""
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).with_name("rerun")
        if exe.is_file() and os.access(exe, os.X_OK):
            return [str(exe)]
    except ImportError:
        pass
    from .info import viewer_command

    return viewer_command()


def _die_with_parent() -> None:  # pragma: no cover - runs in the child before exec
    """Linux: the child gets SIGTERM when we die (even by SIGKILL), so no server outlives us."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except Exception:  # noqa: BLE001 - not Linux: the process group is still ended by us
        pass


def spawn(cmd: list[str], log, env: dict) -> subprocess.Popen:
    """Start a Rerun child: own process group, output to ``log``, ended with us."""
    return subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                            env=env, start_new_session=True,
                            preexec_fn=_die_with_parent if os.name == "posix" else None)


def log_tail(path: str) -> str:
    """The last non-empty line of a child's log file (what a one-line error quotes)."""
    try:
        lines = [ln for ln in Path(path).read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return "no log"
    return lines[-1][:200] if lines else "no log"


def end_group(proc: subprocess.Popen) -> None:
    """End a child started with ``start_new_session=True`` and everything of its process group
    (``rerun`` on PATH may be a wrapper that starts the binary as its child): SIGTERM, then
    SIGKILL; bounded waits."""
    for sig in (signal.SIGTERM, signal.SIGKILL):  # our own process group only
        try:
            os.killpg(proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            break
        try:
            proc.wait(timeout=10)
            time.sleep(0.2)
            os.killpg(proc.pid, 0)  # anything of the group left?
        except ProcessLookupError:
            break
        except Exception:  # noqa: BLE001 - still there: the harder signal
            continue


class WebServer:
    """``rerun`` serving ``rrd``: with ``web=True`` the web viewer on ``web_port`` and the gRPC
    server on ``grpc_port``; with ``web=False`` the gRPC server only (a web viewer already
    running elsewhere connects to it)."""

    def __init__(self, rrd: Path, *, web: bool = True, web_port: Optional[int] = None,
                 grpc_port: Optional[int] = None, timeout: float = 30.0):
        self.rrd = Path(rrd)
        if not self.rrd.is_file():
            raise InputError(f"{rrd}: no such recording")
        self.web_port = web_port or free_port()
        self.grpc_port = grpc_port or free_port()
        self.log = tempfile.NamedTemporaryFile(prefix="pfscope-serve-", suffix=".log",
                                               delete=False)
        cmd = rerun_binary() + (["--serve-web", "--web-viewer-port", str(self.web_port)]
                                  if web else ["--serve-grpc"]) + [
            "--bind", HOST, "--port", str(self.grpc_port), str(self.rrd.resolve())]
        env = {**os.environ, "RERUN_ANALYTICS": "0", "NO_COLOR": "1"}
        try:
            self.proc = spawn(cmd, self.log, env)
        except OSError as e:
            raise RunFailed(f"could not start the Rerun server ({e})") from None
        self.url = viewer_url(self.web_port, self.grpc_port) if web else \
            f"rerun+http://{HOST}:{self.grpc_port}/proxy"
        self._wait(timeout, web)

    def _wait(self, timeout: float, web: bool) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                self.close()
                raise RunFailed(f"the Rerun server exited ({self.tail()})")
            try:
                if web:
                    with urllib.request.urlopen(f"http://{HOST}:{self.web_port}/",
                                                timeout=1) as r:
                        if r.status == 200:
                            return
                else:
                    with socket.create_connection((HOST, self.grpc_port), timeout=0.5):
                        return
            except OSError:
                time.sleep(0.2)
        self.close()
        raise RunFailed(f"the Rerun server did not answer within {timeout:.0f} s ({self.tail()})")

    def tail(self) -> str:
        return log_tail(self.log.name)

    def wait(self) -> int:
        """Until Ctrl-C / SIGTERM (or the server ends): 0 when stopped by a signal."""
        stop = {"sig": None}

        def on_term(signum, frame):  # SIGTERM stops it like Ctrl-C
            stop["sig"] = signum
            raise KeyboardInterrupt

        # both handled here: a process started in the background without a terminal
        # inherits SIGINT ignored, and Ctrl-C / kill -INT must still stop it
        old = {sig: signal.signal(sig, on_term) for sig in (signal.SIGTERM, signal.SIGINT)}
        try:
            while self.proc.poll() is None:
                time.sleep(0.5)
            return 1
        except KeyboardInterrupt:
            return 0
        finally:
            for sig, handler in old.items():
                signal.signal(sig, handler)
            self.close()

    def close(self) -> None:
        end_group(self.proc)
        try:
            self.log.close()
            os.unlink(self.log.name)
        except OSError:
            pass


def cmd_view_web(path: Path, web_port: Optional[int] = None) -> int:
    import sys

    server = WebServer(path, web=True, web_port=web_port)
    print(f"serving {path} at {server.url}  (Ctrl-C to stop)", flush=True)
    try:
        return server.wait()
    finally:
        sys.stdout.flush()


__all__ = ["WebServer", "viewer_url", "free_port", "cmd_view_web", "end_group", "log_tail"]
