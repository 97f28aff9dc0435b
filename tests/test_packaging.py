"""The wheel installs every package folder, and nothing at the top level but ``pfscope``."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from conftest import REPO


def test_every_package_folder_is_listed_in_pyproject():
    cfg = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(cfg["packages"])
    mapping = cfg["package-dir"]
    found = set()
    # a folder mapped to a package of its own (viewer_app/_pfscope is `pfscope` itself) is
    # that package only, not also a subpackage of the folder holding it
    roots = {(REPO / folder).resolve() for folder in mapping.values()}
    for name, folder in mapping.items():
        root = REPO / folder
        for init in root.rglob("__init__.py"):
            inside = [p.resolve() for p in [init.parent, *init.parent.parents]
                      if p.resolve() != root.resolve() and root.resolve() in p.resolve().parents]
            if any(p in roots for p in inside):
                continue
            rel = init.parent.relative_to(root)
            found.add(".".join([name, *rel.parts]) if rel.parts else name)
    assert found == listed, f"missing from pyproject packages: {sorted(found - listed)}; " \
                            f"listed but absent: {sorted(listed - found)}"
    assert all(p.split(".")[0] == "pfscope" for p in listed)


# --- the build backend: `pip install -e .` compiles the numba kernels (viewer_app/_backend) ---

def _backend():
    import importlib
    import sys

    pytest.importorskip("setuptools")
    build = tomllib.loads((REPO / "pyproject.toml").read_text())["build-system"]
    (folder,) = build["backend-path"]
    if str(REPO / folder) not in sys.path:
        sys.path.insert(0, str(REPO / folder))
    return importlib.import_module(build["build-backend"]), REPO / folder


def test_backend_folder_holds_only_the_backend_and_maps_the_packages_as_pyproject():
    """The backend's folder goes on sys.path during a build: it holds that module only (no
    package: trackers/ there would shadow the stdlib's `types`); the install-time compile maps
    the packages to the folders pyproject's package-dir names (numba's cache is keyed by the
    source files' location, so they must be the editable install's)."""
    B, folder = _backend()
    assert sorted(p.name for p in folder.iterdir() if p.name != "__pycache__") == \
        [Path(B.__file__).name]
    assert B.PACKAGE_DIRS == tomllib.loads((REPO / "pyproject.toml").read_text()
                                           )["tool"]["setuptools"]["package-dir"]


def test_editable_build_needs_the_kernel_libraries_with_the_project_specifiers():
    """An editable build (its compile imports them) asks for numba, numpy, scipy and
    opencv-python-headless with [project].dependencies' specifiers, or the target
    environment's installed version (numba's cache index records numba's version); a wheel
    build asks for none of them."""
    B, _ = _backend()
    deps = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["dependencies"]
    mine = [d for d in deps if B._name(d) in B.KERNEL_LIBS]
    assert sorted(map(B._name, mine)) == sorted(B.KERNEL_LIBS)
    assert B.kernel_requirements(installed={}) == mine
    pinned = B.kernel_requirements(installed={"numba": "0.61.2"})
    assert "numba==0.61.2" in pinned and len(pinned) == len(mine)
    assert not any(B._name(r) in B.KERNEL_LIBS for r in B.get_requires_for_build_wheel())


def test_install_compile_failure_is_one_line_and_never_fails_the_install(tmp_path, capsys):
    """No pfscope to import (a broken tree) or out of time: one line on stderr, False, no
    exception (the install goes on; the first run compiles)."""
    B, _ = _backend()
    assert B.compile_kernels(root=tmp_path) is False
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "install-time numba compile failed" in err[0]
    assert B.compile_kernels(timeout=0.01) is False
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "stopped after" in err[0]


@pytest.mark.slow
def test_after_the_install_compile_a_first_run_compiles_nothing(tmp_path):
    """The install-time compile (the backend's subprocess, an empty numba cache) leaves nothing
    for the first `pfscope record` (the README's command, all its frames), nor for the first
    run of each kernel tracker, nor for a crowded scene's K-means
    grid search (a fresh process, the same cache): numba's compile events during the records
    are none."""
    import os
    import subprocess
    import sys

    B, folder = _backend()
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    out = subprocess.run([sys.executable, B.__file__, str(REPO)], env=env, capture_output=True,
                         text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    six = ["--frames", "6"]
    # the README's first command (`pfscope record`: PHD-MT, the whole built-in scene: its
    # later frames reach gap filling and head extension), then the other kernel trackers
    runs = [[], ["--tracker", "phd", "--preset", "paper", *six], ["--tracker", "dbn-phd", *six],
            ["--tracker", "phd-bgsub", *six], ["--tracker", "dlpf", *six],
            # a crowded scene: frames with 16 or more centres take the K-means' grid search
            # (this one's frames 20-30 do, seed 0)
            ["--tracker", "phd", "--targets", "40", "--frames", "30"]]
    code = ("import sys\n"
            f"sys.path.insert(0, {str(folder)!r})\n"
            "import pfscope_build_backend as B\n"
            f"B.map_packages(B.Path({str(REPO)!r}))\n"
            "from numba.core import event as ev\n"
            "from pfscope.viewer_app.cli import main\n"
            "with ev.install_recorder('numba:compile') as r:\n"
            f"    for i, a in enumerate({runs!r}):\n"
            f"        assert main(['record', '--quiet', '--out', "
            f"{str(tmp_path)!r} + f'/r{{i}}.rrd', *a]) in (0, None)\n"
            "print('COMPILED', *sorted({e.data['dispatcher'].py_func.__qualname__ "
            "for _, e in r.buffer if e.is_start}))\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    compiled = out.stdout.split("COMPILED")[-1].split()
    assert compiled == [], compiled
