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
    # a wheel build (`pip install .`) compiles them too: the same list
    wheel = B.get_requires_for_build_wheel()
    assert sorted(B._name(r) for r in wheel if B._name(r) in B.KERNEL_LIBS) == \
        sorted(B.KERNEL_LIBS)


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


#: the README's first command (`pfscope record`: PHD-MT, the whole built-in scene: its later
#: frames reach gap filling and head extension), then the other kernel trackers, then a
#: crowded scene: frames with 16 or more centres take the K-means' grid search (this one's
#: frames 20-30 do, seed 0)
FIRST_RUNS = [[], ["--tracker", "phd", "--preset", "paper", "--frames", "6"],
              ["--tracker", "dbn-phd", "--frames", "6"], ["--tracker", "phd-bgsub", "--frames", "6"],
              ["--tracker", "dlpf", "--frames", "6"],
              ["--tracker", "phd", "--targets", "40", "--frames", "30"]]


def _compiled_by_first_runs(prelude: str, env: dict, out_dir: Path) -> list:
    """The numba kernels :data:`FIRST_RUNS` compile (numba's compile events), in a fresh process
    whose ``pfscope`` is set up by ``prelude``."""
    import subprocess
    import sys

    code = (prelude +
            "from numba.core import event as ev\n"
            "from pfscope.viewer_app.cli import main\n"
            "with ev.install_recorder('numba:compile') as r:\n"
            f"    for i, a in enumerate({FIRST_RUNS!r}):\n"
            f"        assert main(['record', '--quiet', '--out', "
            f"{str(out_dir)!r} + f'/r{{i}}.rrd', *a]) in (0, None)\n"
            "print('COMPILED', *sorted({e.data['dispatcher'].py_func.__qualname__ "
            "for _, e in r.buffer if e.is_start}))\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.split("COMPILED")[-1].split()


@pytest.mark.slow
def test_after_the_install_compile_a_first_run_compiles_nothing(tmp_path):
    """The install-time compile (the backend's subprocess, an empty numba cache) leaves nothing
    for the first `pfscope record` (the README's command, all its frames), nor for the first
    run of each kernel tracker, nor for a crowded scene's K-means grid search (a fresh
    process, the same cache): numba's compile events during the records are none."""
    import os
    import subprocess
    import sys

    B, folder = _backend()
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    out = subprocess.run([sys.executable, B.__file__, "--editable", str(REPO)], env=env,
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    prelude = ("import sys\n"
               f"sys.path.insert(0, {str(folder)!r})\n"
               "import pfscope_build_backend as B\n"
               f"B.map_packages(B.Path({str(REPO)!r}))\n")
    compiled = _compiled_by_first_runs(prelude, env, tmp_path)
    assert compiled == [], compiled


def _source_wheel(B, where: Path) -> Path:
    """A wheel of this checkout's packages laid out as setuptools lays them out (the
    package-dir mapping), with a RECORD: what `pip install .` builds, without a build."""
    import zipfile

    whl = where / "pfscope-0-py3-none-any.whl"
    lines = []
    with zipfile.ZipFile(whl, "w") as z:
        for pkg, folder in B.PACKAGE_DIRS.items():
            root = REPO / folder
            for f in sorted(root.rglob("*")):
                rel = f.relative_to(root)
                if f.is_dir() or "__pycache__" in rel.parts or \
                        (pkg == "pfscope.viewer_app" and rel.parts[0] in ("_pfscope", "_backend")):
                    continue
                arc = "/".join([*pkg.split("."), *rel.parts])
                data = f.read_bytes()
                z.writestr(arc, data)
                lines.append(B._record_line(arc, data))
        z.writestr("pfscope-0.dist-info/RECORD", "\n".join(lines + [
            "pfscope-0.dist-info/RECORD,,"]) + "\n")
    return whl


@pytest.mark.slow
def test_a_wheel_carries_its_kernels_and_a_first_run_from_it_compiles_nothing(tmp_path):
    """`pip install .` (a wheel): the backend compiles the kernels with pfscope imported from
    the unpacked wheel and adds numba's cache files to it, each listed in RECORD with its hash
    (RECORD still last).  Installed elsewhere (another folder, no NUMBA_CACHE_DIR: numba's
    in-tree cache), the first runs compile nothing; a wheel whose compile fails stays as it
    was."""
    import base64
    import hashlib
    import os
    import zipfile

    B, _ = _backend()
    whl = _source_wheel(B, tmp_path)
    before = whl.read_bytes()
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    assert B.add_kernel_cache(whl, timeout=0.01) == 0          # out of time: unchanged
    assert whl.read_bytes() == before
    assert not list(tmp_path.glob("*.incomplete"))
    added = B.add_kernel_cache(whl)
    assert added > 0
    with zipfile.ZipFile(whl) as z:
        names = z.namelist()
        cache = [n for n in names if n.endswith((".nbi", ".nbc"))]
        assert len(cache) == added
        record = z.read("pfscope-0.dist-info/RECORD").decode().splitlines()
        assert record[-1] == "pfscope-0.dist-info/RECORD,,"
        listed = {line.split(",")[0]: line for line in record}
        for n in cache:
            data = z.read(n)
            digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=")
            assert listed[n] == f"{n},sha256={digest.decode()},{len(data)}"
        site = tmp_path / "site-packages"
        z.extractall(site)
    prelude = (f"import sys\nsys.path.insert(0, {str(site)!r})\nimport pfscope\n"
               f"assert pfscope.__file__.startswith({str(site)!r}), pfscope.__file__\n")
    compiled = _compiled_by_first_runs(prelude, env, tmp_path)
    assert compiled == [], compiled
