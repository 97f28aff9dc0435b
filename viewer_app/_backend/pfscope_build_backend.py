"""pfscope's build backend: setuptools' own (every hook unchanged), plus the numba kernels
compiled into numba's cache at build time, so the first run after ``pip install -e .`` or
``pip install .`` starts as fast as a later one.

``pyproject.toml`` names this module (``build-backend``, ``backend-path``); it lives alone in
its folder, so that folder on ``sys.path`` shadows nothing.

* ``get_requires_for_build_editable``: setuptools' list plus the kernels' libraries (numba,
  numpy, scipy, opencv-python-headless) with the specifiers of ``[project].dependencies``, or
  pinned to the version the target environment already has (numba's cache index records
  numba's version: a cache written by another version would be compiled again at first run).
  ``get_requires_for_build_wheel`` adds the same list.  An sdist build needs none of them.
* ``build_editable``: setuptools' ``build_editable``, then, in a subprocess of the same
  interpreter with the build environment's ``sys.path`` and a bounded time
  (``PFSCOPE_INSTALL_COMPILE_TIMEOUT``, default 900 s), ``pfscope.trackers.warmup.
  compile_for_install`` with the packages mapped to the source folders the way the editable
  install maps them (real paths: numba's cache is keyed by the source file's location).
  ``PFSCOPE_INSTALL_COMPILE=0`` skips it.  Any failure prints one line to stderr and never
  fails the install: the first run then compiles, as without this step.
* ``build_wheel`` (``pip install .``): setuptools' ``build_wheel``, then the same compile with
  ``pfscope`` imported from the unpacked wheel, and numba's cache files it wrote there
  (``__pycache__/*.nbi``, ``*.nbc``, next to the modules: numba's in-tree cache, whose index
  is keyed by the source's content hash, numba's version and the CPU, not by the path) added
  to the wheel and its ``RECORD``.  On another CPU or numba they are not used (numba compiles
  as without them).  ``PFSCOPE_INSTALL_COMPILE=0`` builds a wheel without them (for a wheel
  meant for other machines).
"""

from __future__ import annotations

import base64
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

if __name__ != "__main__":          # the compile's subprocess (below) needs no setuptools
    from setuptools import build_meta as _orig
    from setuptools.build_meta import *  # noqa: F401,F403  (every hook, unchanged)

#: the kernels' libraries: the install-time compile imports them in the build environment
KERNEL_LIBS = ("numba", "numpy", "scipy", "opencv-python-headless")
#: the editable install's package folders (pyproject's [tool.setuptools] package-dir)
PACKAGE_DIRS = {"pfscope": "viewer_app/_pfscope", "pfscope.trackers": "trackers",
                "pfscope.viewer_app": "viewer_app"}
ROOT = Path(__file__).resolve().parents[2]


def _name(req: str) -> str:
    return re.split(r"[\s<>=!~;\[(]", req.strip(), maxsplit=1)[0].lower().replace("_", "-")


def _installed_versions() -> dict:
    """The versions of :data:`KERNEL_LIBS` installed in the target environment (pip's build
    isolation runs this with the target's interpreter, its site-packages off ``sys.path``)."""
    import sysconfig
    from importlib import metadata

    paths = list(dict.fromkeys(sysconfig.get_paths()[k] for k in ("purelib", "platlib")))
    found = {}
    for dist in metadata.distributions(path=paths):
        name = _name(dist.metadata["Name"] or "")
        if name in KERNEL_LIBS:
            found[name] = dist.version
    return found


def kernel_requirements(root: Path = ROOT, installed: dict | None = None) -> list:
    """The :data:`KERNEL_LIBS` entries of ``[project].dependencies``, each pinned to the target
    environment's version when it has one (``installed``: name -> version)."""
    try:
        import tomllib
    except ImportError:                               # Python 3.10
        try:
            import tomli as tomllib
        except ImportError:
            return []
    deps = tomllib.loads((root / "pyproject.toml").read_text())["project"]["dependencies"]
    installed = _installed_versions() if installed is None else installed
    return [f"{_name(d)}=={installed[_name(d)]}" if _name(d) in installed else d
            for d in deps if _name(d) in KERNEL_LIBS]


def _compile_wanted() -> bool:
    return os.environ.get("PFSCOPE_INSTALL_COMPILE", "1") != "0"


def _with_kernel_libs(reqs) -> list:
    reqs = list(reqs)
    if _compile_wanted():
        try:
            reqs += kernel_requirements()
        except Exception as e:                      # never fail the install over it
            print(f"pfscope: no install-time compile ({type(e).__name__}: {e})",
                  file=sys.stderr)
    return reqs


def get_requires_for_build_editable(config_settings=None):
    return _with_kernel_libs(_orig.get_requires_for_build_editable(config_settings))


def get_requires_for_build_wheel(config_settings=None):
    return _with_kernel_libs(_orig.get_requires_for_build_wheel(config_settings))


def build_editable(wheel_directory, config_settings=None, metadata_directory=None):
    name = _orig.build_editable(wheel_directory, config_settings, metadata_directory)
    if _compile_wanted():
        compile_kernels()
    return name


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    name = _orig.build_wheel(wheel_directory, config_settings, metadata_directory)
    if _compile_wanted():
        add_kernel_cache(Path(wheel_directory) / name)
    return name


def _record_line(arcname: str, data: bytes) -> str:
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"{arcname},sha256={digest},{len(data)}"


def add_kernel_cache(wheel: Path, timeout: float | None = None) -> int:
    """Compile the kernels with ``pfscope`` imported from ``wheel`` unpacked, and add numba's
    cache files written next to its modules to ``wheel`` (rewritten under a temporary name,
    then renamed) and to its ``RECORD``.  Returns how many files were added (0 when the
    compile failed: one line on stderr, the wheel unchanged)."""
    with tempfile.TemporaryDirectory(prefix="pfscope-wheel-") as tmp:
        unpacked = Path(tmp) / "w"
        with zipfile.ZipFile(wheel) as z:
            z.extractall(unpacked)
            names = z.namelist()
        if not compile_kernels(unpacked, timeout=timeout, mode="--wheel"):
            return 0
        cache = sorted(p for p in unpacked.rglob("__pycache__/*")
                       if p.suffix in (".nbi", ".nbc"))
        (record,) = [n for n in names if n.endswith(".dist-info/RECORD")]
        part = wheel.with_name(wheel.name + ".incomplete")
        with zipfile.ZipFile(wheel) as src, \
                zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as dst:
            lines = src.read(record).decode().splitlines()
            for info in src.infolist():
                if info.filename != record:
                    dst.writestr(info, src.read(info))
            for p in cache:
                arc = p.relative_to(unpacked).as_posix()
                data = p.read_bytes()
                dst.writestr(arc, data)
                lines.insert(len(lines) - 1, _record_line(arc, data))   # RECORD stays last
            dst.writestr(record, "\n".join(lines) + "\n")
        os.replace(part, wheel)
    print(f"pfscope: {len(cache)} numba cache files added to {wheel.name}")
    return len(cache)


def compile_kernels(root: Path = ROOT, timeout: float | None = None,
                    mode: str = "--editable") -> bool:
    """Run :func:`compile_for_install` in a subprocess (see the module's doc): ``pfscope``
    mapped to ``root``'s source folders (``mode`` "--editable") or imported from ``root``, an
    unpacked wheel ("--wheel"), numba's cache next to the modules.  True when it succeeded,
    else one line on stderr and False."""
    timeout = float(os.environ.get("PFSCOPE_INSTALL_COMPILE_TIMEOUT", 900)
                    if timeout is None else timeout)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    if mode == "--wheel":
        env.pop("NUMBA_CACHE_DIR", None)            # the cache must land next to the modules
    t0 = time.perf_counter()
    try:
        out = subprocess.run([sys.executable, str(Path(__file__).resolve()), mode, str(root)],
                             env=env, stdin=subprocess.DEVNULL, capture_output=True,
                             text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        print(f"pfscope: install-time numba compile stopped after {timeout:.0f} s; the first "
              f"run compiles the rest", file=sys.stderr)
        return False
    except OSError as e:
        print(f"pfscope: install-time numba compile did not start ({e}); the first run "
              f"compiles", file=sys.stderr)
        return False
    if out.returncode != 0:
        last = (out.stderr.strip().splitlines() or ["exit code %d" % out.returncode])[-1]
        print(f"pfscope: install-time numba compile failed ({last}); the first run compiles",
              file=sys.stderr)
        return False
    # pip shows a backend's output only with -v
    print(out.stdout, end="")
    print(f"pfscope: numba kernels compiled (or found) in numba's cache in "
          f"{time.perf_counter() - t0:.1f} s (the first run loads them)")
    return True


def map_packages(root: Path) -> None:
    """Import ``pfscope`` and its subpackages from ``root``'s folders (:data:`PACKAGE_DIRS`,
    real paths) as the editable install does."""
    import importlib.util

    dirs = {n: str((root / d).resolve()) for n, d in PACKAGE_DIRS.items()}

    class Finder:
        @classmethod
        def find_spec(cls, name, path=None, target=None):
            if name not in dirs:
                return None
            return importlib.util.spec_from_file_location(
                name, os.path.join(dirs[name], "__init__.py"),
                submodule_search_locations=[dirs[name]])

    sys.meta_path.insert(0, Finder)


if __name__ == "__main__":                          # the subprocess of compile_kernels
    sys.path[:] = [p for p in sys.path
                   if Path(p or ".").resolve() != Path(__file__).resolve().parent]
    if sys.argv[1] == "--wheel":
        sys.path.insert(0, sys.argv[2])
        import pfscope

        if not Path(pfscope.__file__).resolve().is_relative_to(Path(sys.argv[2]).resolve()):
            sys.exit(f"pfscope imported from {pfscope.__file__}, not the wheel")
    else:
        map_packages(Path(sys.argv[2]))
    from pfscope.trackers.warmup import compile_for_install

    compile_for_install()
