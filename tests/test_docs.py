"""The README and the docs site say what the code does: the CLI synopsis and reference are the
parsers' own, every README command and code block runs, the site builds strictly, and the
README's numbers are the docs pages' numbers.  Also the command line's one language:
``--version``, ``--frames``, "did you mean", API words."""

from __future__ import annotations

import argparse
import os
import re
import shlex
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from conftest import REPO, data_root

README = REPO / "README.md"
TEST_COMMAND = ('python3 -m venv .venv && . .venv/bin/activate && pip install -e ".[test]" && '
                'pip install --no-deps "trackeval==1.3.0" && python -m pytest -q')


def _blocks(lang: str) -> list[str]:
    text = README.read_text(encoding="utf-8")
    return [m.group(1) for m in re.finditer(rf"^```{lang}\n(.*?)^```", text, re.S | re.M)]


def _parser():
    from pfscope.viewer_app.cli import build_parser

    return build_parser()


# --- generated documentation ------------------------------------------------------------------

def test_readme_synopsis_and_cli_page_are_generated_from_the_parsers():
    """In a fresh process, as the lead runs it: other tests register trackers of their own in
    this one, and those are not pfscope's."""
    r = subprocess.run([sys.executable, "-m", "pfscope.viewer_app.docgen", "--check",
                        "--root", str(REPO)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, (f"{r.stderr.strip()}: run `python -m pfscope.viewer_app.docgen`")


def test_the_synopsis_names_every_subcommand_and_option():
    """Independent of the generator's formatting: every subcommand and every option string of
    every parser is in the README's synopsis block and on the CLI page."""
    from pfscope.viewer_app.docgen import BEGIN, END

    text = README.read_text(encoding="utf-8")
    block = text.split(BEGIN, 1)[1].split(END, 1)[0]
    page = (REPO / "docs" / "cli.md").read_text(encoding="utf-8")
    ap = _parser()
    sub = next(a for a in ap._actions if isinstance(a, argparse._SubParsersAction))
    assert "--version" in block
    for name, p in sub.choices.items():
        assert f"pfscope {name} " in block + " " and f"## {name}" in page, name
        usage = block.split(f"pfscope {name} ", 1)[1].split("\npfscope ", 1)[0]
        for a in p._actions:
            for opt in a.option_strings:
                if opt in ("-h", "--help"):
                    continue
                if len(opt) > 2 and opt == max(a.option_strings, key=len):
                    assert re.search(rf"{re.escape(opt)}\b", usage), f"{name}: {opt}"
                    assert f"`{opt}`" in page, f"cli.md {name}: {opt}"


def test_docgen_check_fails_on_a_stale_file(tmp_path):
    """The one command the lead runs after a merge: --check says which file is stale."""
    from pfscope.viewer_app import docgen

    root = tmp_path / "repo"
    (root / "docs").mkdir(parents=True)
    shutil.copy(README, root / "README.md")
    (root / "docs" / "cli.md").write_text("old\n")
    assert docgen.main(["--check", "--root", str(root)]) == 1
    assert (root / "docs" / "cli.md").read_text() == "old\n"       # --check writes nothing
    assert docgen.main(["--root", str(root)]) == 0
    assert docgen.main(["--check", "--root", str(root)]) == 0
    assert (root / "docs" / "cli.md").read_text() == docgen.reference()


def test_readme_is_a_short_guide():
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 400
    pages = [README, *sorted((REPO / "docs").rglob("*.md"))]   # the changelog is CHANGELOG.md
    for page in pages:
        if "api-src" in page.parts:
            continue
        body = page.read_text(encoding="utf-8").lower().replace("its issue #132", "")
        for word in ("issue ", "previous release", "this round", "before/after"):
            assert word not in body, f"{page.name}: {word!r} (history goes to CHANGELOG.md)"
    for tracker in _parser_trackers():
        assert f"`{tracker}`" in text, tracker


def _parser_trackers() -> list[str]:
    """The built-in trackers (tests register their own in this process)."""
    from pfscope.trackers.api import registry

    return [n for n, i in registry().items() if i.cls.__module__.startswith("pfscope.trackers.")]


def test_readme_test_command_is_the_one_ci_runs():
    text = README.read_text(encoding="utf-8")
    assert TEST_COMMAND in text
    assert TEST_COMMAND in (REPO / ".ci" / "run").read_text()


def test_readme_numbers_are_the_docs_numbers():
    """Each "how good and how fast" table's numbers appear on the page it links to (or, for
    the step times, the benchmarks page): one source for every number."""
    text = README.read_text(encoding="utf-8")
    part = text.split("## How good and how fast", 1)[1].split("\n## ", 1)[0]
    bench = (REPO / "docs" / "benchmarks.md").read_text(encoding="utf-8")
    sections = re.split(r"\n(?=\*\*[^*]+\*\* \(\[details\])", part)
    checked = 0
    for sec in sections[1:]:
        page = REPO / re.search(r"\[details\]\(([^)#]+)", sec).group(1)
        body = page.read_text(encoding="utf-8")
        rows = [ln for ln in sec.splitlines() if ln.startswith("| ") and "---" not in ln][1:]
        for row in rows:
            for cell in row.strip("| ").split(" | "):
                num = re.search(r"\d+\.\d+", cell)
                if num is None:
                    continue
                where = bench if cell.endswith("ms") else body
                assert num.group(0) in where, f"{num.group(0)} ({cell}) not in {page.name}"
                checked += 1
    assert checked >= 15


@pytest.mark.slow
def test_mkdocs_build_strict(tmp_path):
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings")
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir",
                        str(tmp_path / "site")], cwd=REPO, capture_output=True, text=True,
                       timeout=600, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert r.returncode == 0, r.stderr[-3000:]
    api = (tmp_path / "site" / "api" / "index.html").read_text(encoding="utf-8")
    assert "tracks_out" in api and "make_tracker" in api      # docstrings were rendered
    for page in ("guide", "cli", "benchmarks", "recording-format", "trackers/dbn-phd"):
        assert (tmp_path / "site" / page / "index.html").exists(), page


# --- every README command and code block runs ----------------------------------------------------

#: Commands the test does not run, and why (all are covered elsewhere).
NOT_RUN = {
    "python3 -m venv": "the set-up itself: .ci/run runs it from scratch",
    "rerun ": "opens the viewer (needs a display)",
}


def _bash_script(data: Path) -> str:
    lines = []
    for block in _blocks("bash"):
        for line in block.replace("\\\n", " ").splitlines():
            cmd = line.split("   #", 1)[0].strip()
            if not cmd or cmd.startswith("#"):
                continue
            if any(cmd.startswith(p) for p in NOT_RUN):
                tail = cmd.rsplit("&&", 1)[-1].strip()
                if cmd.startswith("python3 -m venv") and tail.startswith("pfscope "):
                    lines.append(tail + " --frames 5")   # command 1's record, kept short
                continue
            lines.append(cmd)
    script = "\n".join(lines).replace("../shared/data", str(data))
    return "set -euo pipefail\n" + script + "\n"


@pytest.mark.slow
def test_every_readme_command_runs(tmp_path):
    data = data_root()
    if data is None or not (data / "PETS09-S2L1").is_dir():
        pytest.skip("PETS09-S2L1 not found: set PFSCOPE_DATA (default ../shared/data)")
    script = _bash_script(data)
    assert "pfscope record" in script and "pfscope eval" in script
    bindir = str(Path(sys.executable).parent)
    env = {**os.environ, "PATH": bindir + os.pathsep + os.environ.get("PATH", ""),
           "RERUN_ANALYTICS": "0"}
    r = subprocess.run(["bash", "-c", script], cwd=tmp_path, capture_output=True, text=True,
                       timeout=900, env=env)
    assert r.returncode == 0, f"{r.stderr[-3000:]}\n--- script:\n{script}"
    assert (tmp_path / "recordings" / "synthetic-seed0-phd.rrd").exists()
    assert (tmp_path / "pets.txt").stat().st_size > 0
    assert "MOTA" in r.stdout


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(_blocks("python")) - 1))
def test_every_readme_python_block_runs(tmp_path, index):
    """The README's Python blocks (the last one, the passthrough class, is the real file's
    code: tests/test_platform.py runs it)."""
    data = data_root()
    if data is None or not (data / "PETS09-S2L1").is_dir():
        pytest.skip("PETS09-S2L1 not found: set PFSCOPE_DATA (default ../shared/data)")
    code = _blocks("python")[index].replace("../shared/data", str(data))
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                       text=True, timeout=600, env={**os.environ, "RERUN_ANALYTICS": "0"})
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.strip()


def test_readme_passthrough_listing_is_the_real_file():
    """The "Adding a tracker" listing is passthrough.py's class, line for line (comments aside)."""
    block = _blocks("python")[-1]
    src = (REPO / "trackers" / "passthrough.py").read_text(encoding="utf-8")

    def code(text: str) -> list[str]:
        return [ln.split("#", 1)[0].rstrip() for ln in text.splitlines()
                if ln.split("#", 1)[0].strip()]

    listed, real = code(block), code(src)
    start = real.index(listed[0])
    assert real[start:start + len(listed)] == listed


# --- one command-line language --------------------------------------------------------------

def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pfscope.viewer_app.cli", *args],
                          capture_output=True, text=True, timeout=300,
                          env={**os.environ, "RERUN_ANALYTICS": "0"})


def test_version():
    import pfscope
    import tomllib

    want = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]
    r = _cli("--version")
    assert r.returncode == 0 and r.stdout.strip() == f"pfscope {want}"
    assert pfscope.__version__ == want


@pytest.mark.parametrize("args,hint", [
    (["recrod"], "did you mean 'record'?"),
    (["record", "--tracker", "dlfp"], "did you mean 'dlpf'?"),
    (["record", "--detector", "hgo"], "did you mean 'hog'?"),
    (["trackers", "ph"], "did you mean 'phd'?"),
    (["record", "--frames", "2", "--set", "p_mis=0.2"], "did you mean 'p_miss'?"),
    (["record", "--frames", "2", "--preset", "papr"], "did you mean 'paper'?"),
    (["compare", "--frames", "2", "--trackers", "phd,mtt"], "did you mean 'mt'?"),
])
def test_did_you_mean(args, hint, tmp_path):
    r = _cli(*args, *(["--out", str(tmp_path / "x.rrd")] if args[0] in ("record", "compare")
                     else []))
    assert r.returncode == 2, r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert hint in last and "Traceback" not in r.stderr


def test_unknown_parameter_does_not_list_every_name():
    from pfscope.trackers.api import make_tracker

    with pytest.raises(ValueError) as e:
        make_tracker("phd", p_mis=0.1)
    msg = str(e.value)
    assert "did you mean 'p_miss'?" in msg and "sigma_v" not in msg and len(msg) < 200
    with pytest.raises(ValueError, match="unknown parameter 'zzzz';"):  # nothing close: no hint
        make_tracker("phd", zzzz=1)


@pytest.mark.parametrize("args", [
    ["record", "--frames", "1-20"],
    ["eval", "t.txt", "--gt", "g.txt", "--frames", "1-20"],
    ["train-dbn", "synthetic", "--out", "m.pt", "--frames", "1-20"],
    ["train-classifier", "synthetic", "--out", "m.npz", "--frames", "1-20"],
    ["tune", "synthetic", "--frames", "1-20"],
    ["batch", "--frames", "1-20", "--out", "runs"],
])
def test_frames_dash_form_is_refused_with_the_right_example(args, tmp_path):
    r = subprocess.run([sys.executable, "-m", "pfscope.viewer_app.cli", *args], cwd=tmp_path,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2
    assert "'1-20': write FIRST:LAST, e.g. 1:20" in r.stderr.strip().splitlines()[-1]


def test_training_commands_read_frames_like_every_command():
    from pfscope.viewer_app.cli import build_parser, frames_within
    from pfscope.trackers.errors import InputError

    ap = build_parser()
    for cmd in ("train-dbn", "train-classifier"):
        a = ap.parse_args([cmd, "synthetic", "--out", "m", "--frames", "1:400"])
        assert a.frames == (1, 400)
        assert ap.parse_args([cmd, "synthetic", "--out", "m", "--frames", "40"]).frames == 40
    assert frames_within(40, 795, "s") == (1, 40)
    assert frames_within((401, 795), 795, "s") == (401, 795)
    assert frames_within(None, 795, "s") == (1, 795)
    with pytest.raises(InputError, match="has 795 frames"):
        frames_within((1, 800), 795, "s")
    assert ap.parse_args(["eval", "t", "--gt", "g", "--frames", "30"]).frames == (1, 30)


def test_api_errors_speak_the_api(tmp_path):
    import pfscope
    from pfscope.trackers.errors import InputError

    out = tmp_path / "x.rrd"
    out.write_bytes(b"precious")
    with pytest.raises(InputError) as e:
        pfscope.record(None, out=out, frames=2)
    assert "force=True" in str(e.value) and "--force" not in str(e.value)
    assert out.read_bytes() == b"precious"


def test_cli_overwrite_error_names_the_flag(tmp_path, capsys):
    from pfscope.viewer_app.cli import main

    out = tmp_path / "x.rrd"
    out.write_bytes(b"precious")
    assert main(["record", "--frames", "2", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--force" in err and "force=True" not in err


# --- project files ----------------------------------------------------------------------------

def test_versions_name_every_library_that_shapes_results():
    from importlib import metadata

    from pfscope.viewer_app.recorder import versions

    v = versions()
    for name in ("pfscope", "rerun-sdk", "numpy", "scipy", "opencv", "numba", "torch", "python"):
        assert v.get(name), name
    assert v["torch"] == metadata.version("torch") and v["numba"] == metadata.version("numba")


def test_synth_names_the_sequence_after_its_folder(tmp_path):
    import configparser

    from pfscope.viewer_app.cli import main

    out = tmp_path / "my-scene"
    assert main(["synth", "--out", str(out), "--frames", "3", "--quiet"]) == 0
    cp = configparser.ConfigParser()
    cp.read(out / "seqinfo.ini")
    assert cp["Sequence"]["name"] == "my-scene"


def test_license_and_changelog():
    import tomllib

    lic = (REPO / "LICENSE").read_text()
    assert lic.startswith("MIT License")
    meta = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    assert meta["license"]["text"] == "MIT"
    assert f"## {meta['version']}" in (REPO / "CHANGELOG.md").read_text()


@pytest.mark.slow
def test_wheel_ships_py_typed_and_license(tmp_path):
    """Build the wheel as pip would (no network: the build backend is the venv's setuptools)."""
    pytest.importorskip("setuptools")
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                        "--no-build-isolation", "-q", "-w", str(tmp_path), str(REPO)],
                       capture_output=True, text=True, timeout=600)
    if r.returncode != 0 and "No module named" in r.stderr:
        pytest.skip(f"cannot build a wheel here: {r.stderr.strip().splitlines()[-1]}")
    assert r.returncode == 0, r.stderr[-2000:]
    wheel = next(tmp_path.glob("pfscope-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    assert "pfscope/py.typed" in names
    assert any(n.endswith("LICENSE") for n in names)
    assert not [n for n in names if n.split("/")[0] not in ("pfscope",)
                and ".dist-info" not in n.split("/")[0]]
