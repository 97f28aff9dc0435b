"""No silent settings, inputs never overwritten, and the one-line errors of issue 23's list."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time

import pytest

from conftest import REPO, read_rrd
from test_record import _toy
from test_reliability import cli, one_line_error

from pfscope.trackers.api import make_params, param_origins, registry
from pfscope.trackers.params import leaves


def _other(v):
    """A different value of the same type, or None (strings: file names, modes)."""
    if isinstance(v, bool):
        return not v
    if isinstance(v, int):
        return v + 1
    if isinstance(v, float) and math.isfinite(v):
        return v * 0.9 if v else 0.01
    return None


def _effective(p):
    at_fps = getattr(p, "at_fps", None)
    return p.at_fps(p.rate.fallback_fps) if callable(at_fps) else p


def _cases():
    for name, info in sorted(registry().items()):
        for preset in info.presets:
            yield name, preset


@pytest.mark.parametrize("tracker,preset", list(_cases()))
def test_every_parameter_either_takes_effect_or_is_refused(tracker, preset):
    """Walk every registered parameter of every preset: setting it to another value changes
    the settings the tracker runs with (after the per-second conversion), or is refused with
    a line naming what to set instead.  Never accepted and ignored."""
    base = make_params(tracker, preset)
    eff0 = {n: v for n, _, v in leaves(_effective(base))}
    checked = 0
    for name, _, v in leaves(base):
        new = _other(v)
        if new is None:
            continue
        try:
            p = make_params(tracker, preset, {name: new})
        except ValueError as e:
            # refused: either out of its valid range, or a setting nothing would read
            msg = str(e)
            assert name in msg or "rate." in msg, msg
            if "rate." in msg:
                assert "derived" in msg or "read only" in msg, msg
            continue
        eff = {n: x for n, _, x in leaves(_effective(p))}
        assert eff[name] != eff0[name], f"{tracker}/{preset}: {name}={new!r} accepted but " \
                                        f"the tracker runs with {eff[name]!r} as before"
        checked += 1
    assert checked > 0 or not any(_other(v) is not None for _, _, v in leaves(base))


def test_set_depth_under_practical_is_refused_naming_the_rate_field():
    with pytest.raises(ValueError, match=r"assoc.depth is derived each frame from rate.gap_s"):
        make_params("phd", "practical", {"depth": "30"})
    with pytest.raises(ValueError, match=r"rate.min_track_s"):
        make_params("mt", "practical", {"min_length": "9"})
    # without the derivation it takes effect; and the rate field under paper is refused
    assert make_params("phd", "paper", {"depth": "30"}).assoc.depth == 30
    with pytest.raises(ValueError, match=r"read only when rate.per_second = true"):
        make_params("phd", "paper", {"gap_s": "3"})
    # writing a field's current value (a parameters file lists every field) is no change
    cur = make_params("phd", "practical").assoc.depth
    assert make_params("phd", "practical", {"assoc.depth": cur}).assoc.depth == cur


def test_cli_set_depth_under_practical_is_one_line(tmp_path):
    r = cli("record", "--frames", "2", "--set", "depth=30", "--out", tmp_path / "x.rrd",
            "--quiet")
    assert "rate.gap_s" in one_line_error(r)
    assert not list(tmp_path.iterdir())


def test_info_shows_the_effective_value_and_where_it_came_from(tmp_path, capsys):
    from pfscope.viewer_app.cli import main

    root = _toy(tmp_path)
    out = tmp_path / "x.rrd"
    assert main(["record", str(root), "--tracker", "mt", "--set", "gap_s=3", "--out",
                 str(out), "--quiet"]) == 0
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    line = next(ln for ln in text.splitlines() if ln.strip().startswith("assoc.depth ="))
    # toy: 5 fps, gap_s 3 → depth ceil(15) = 15
    assert "in effect 15" in line and "derived each frame from rate.gap_s" in line, line
    assert "(set)" in next(ln for ln in text.splitlines() if "rate.gap_s =" in ln)
    assert "preset practical" in next(ln for ln in text.splitlines() if "assoc.gate =" in ln)
    o = param_origins("mt", None, make_params("mt", None, {"gap_s": 3}), 5.0)
    assert o["assoc.depth"][0] == 15


# ----------------------------------------------------------------------------- inputs sacred

@pytest.mark.parametrize("which", ["gt/gt.txt", "det/det.txt", "seqinfo.ini",
                                   "img1/000001.jpg"])
def test_an_output_onto_an_input_is_refused_even_with_force(tmp_path, which):
    root = _toy(tmp_path)
    target = root / which
    before = target.read_bytes()
    r = cli("record", root, "--tracker", "passthrough", "--out", tmp_path / "x.rrd",
            "--tracks-out", target, "--force", "--quiet")
    assert "is an input of this run" in one_line_error(r)
    r = cli("record", root, "--tracker", "passthrough", "--out", target, "--force", "--quiet")
    assert "is an input of this run" in one_line_error(r)
    assert target.read_bytes() == before


def test_a_link_to_an_input_and_the_params_file_are_inputs_too(tmp_path):
    root = _toy(tmp_path)
    link = tmp_path / "link.txt"
    link.symlink_to(root / "gt" / "gt.txt")
    r = cli("record", root, "--tracker", "passthrough", "--out", tmp_path / "x.rrd",
            "--tracks-out", link, "--force", "--quiet")
    assert "is an input of this run" in one_line_error(r)
    pf = tmp_path / "p.toml"
    pf.write_text('tracker = "mt"\n[params.assoc]\ngate = 0.5\n')
    r = cli("record", root, "--params", pf, "--out", pf, "--force", "--quiet")
    assert "is an input of this run" in one_line_error(r)
    assert "gate = 0.5" in pf.read_text()


# ----------------------------------------------------------------------------- issue 23's list

def test_seqinfo_without_frame_rate_needs_fps(tmp_path):
    root = _toy(tmp_path)
    ini = root / "seqinfo.ini"
    ini.write_text(ini.read_text().replace("frameRate=5\n", ""))
    r = cli("record", root, "--tracker", "passthrough", "--out", tmp_path / "x.rrd", "--quiet")
    assert "no frameRate" in one_line_error(r)
    r = cli("record", root, "--tracker", "passthrough", "--fps", "7", "--out",
            tmp_path / "x.rrd", "--quiet", "--json" if False else "--quiet")
    assert r.returncode == 0, r.stderr
    from pfscope.viewer_app.properties import read_properties

    assert read_properties(tmp_path / "x.rrd")["source"]["fps"] in (7.0, [7.0])


@pytest.mark.parametrize("content", [b"", b"RRF2" + b"\0" * 96, os.urandom(4096),
                                     b"PK\x03\x04 a zip file, not a recording" * 10])
def test_repair_info_snapshot_refuse_what_is_not_a_recording(tmp_path, content):
    f = tmp_path / "bad.rrd"
    f.write_bytes(content)
    r = cli("repair", f)
    one_line_error(r)
    assert not (tmp_path / "bad.repaired.rrd").exists()
    one_line_error(cli("info", f))
    one_line_error(cli("snapshot", f, "--out", tmp_path / "s.png"))   # before any viewer
    assert not (tmp_path / "s.png").exists()


def test_info_on_a_cut_short_recording_is_one_line_or_works(tmp_path):
    out = tmp_path / "x.rrd"
    assert cli("record", "--frames", "5", "--out", out, "--quiet").returncode == 0
    data = out.read_bytes()
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(data[: len(data) // 2])
    # cut inside an entry: read up to its last whole entry, and said in info's first line
    r = cli("info", cut)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    head = r.stdout.splitlines()[0]
    assert "cut inside an entry" in head and "pfscope repair" in head, head
    assert "Warning" not in r.stderr, r.stderr         # Rerun's no-footer warning is ours to say
    # the Rerun viewer refuses such a file: one line that says what to do, before any viewer
    line = one_line_error(cli("view", cut))
    assert "cut inside an entry" in line and f"pfscope repair {cut}" in line, line


def test_repair_takes_a_name_starting_with_a_dash(tmp_path):
    out = tmp_path / "x.rrd"
    assert cli("record", "--frames", "3", "--out", out, "--quiet").returncode == 0
    dash = tmp_path / "-x.rrd"
    out.rename(dash)
    r = cli("repair", "--", "-x.rrd", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "-x.repaired.rrd").exists()


def test_batch_spec_and_out_errors_are_one_line(tmp_path):
    spec = tmp_path / "b.toml"
    spec.write_text('set = 3\nout = "runs"\n')
    assert "'set' must be a table" in one_line_error(cli("batch", spec))
    spec.write_text('workers = "two"\nout = "runs"\n')
    assert "'workers' must be an integer" in one_line_error(cli("batch", spec))
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert "not a folder" in one_line_error(cli("batch", "--frames", "2", "--out", blocker))
    if os.geteuid() != 0:  # root writes anywhere
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        assert "not writable" in one_line_error(cli("batch", "--frames", "2", "--out", ro))


def test_sigterm_on_record_exits_143_and_keeps_an_incomplete_file(tmp_path):
    out = tmp_path / "x.rrd"
    p = subprocess.Popen([sys.executable, "-m", "pfscope.viewer_app.cli", "record",
                          "--tracker", "passthrough", "--frames", "100000", "--out", str(out),
                          "--quiet"], cwd=REPO, env=dict(os.environ, RERUN_ANALYTICS="0"),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        t0 = time.time()
        while not (tmp_path / ".x.rrd.lock").exists() and time.time() - t0 < 60:
            time.sleep(0.1)
        time.sleep(1.0)
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 143, err
    read_rrd(tmp_path / "x.incomplete.rrd")
    assert not out.exists()


def test_ids_are_parsed_as_integers(tmp_path):
    from pfscope.trackers.data.motio import read_mot

    big = 2 ** 53 + 1
    f = tmp_path / "t.txt"
    f.write_text(f"1,{big},0,0,10,10,-1,-1,-1,-1\n2,{big + 2},0,0,10,10,-1,-1,-1,-1\n"
                 "3,7.0,0,0,10,10,-1,-1,-1,-1\n")
    t = read_mot(f, "tracks")
    assert t.id.tolist() == [big, big + 2, 7]
    f.write_text(f"1,{2 ** 64},0,0,10,10,-1,-1,-1,-1\n")
    with pytest.raises(Exception, match="64-bit"):
        read_mot(f, "tracks")


@pytest.mark.parametrize("argv", [["trackers"], ["--help"], ["info", "--help"],
                                  ["synth", "--frames", "2", "--quiet"],
                                  ["batch", "--trackers", "passthrough", "--frames", "2",
                                   "--workers", "1", "--quiet"]])
def test_stdout_to_a_full_device_is_one_line(tmp_path, argv):
    if argv[0] != "trackers":
        argv = argv + ["--out", str(tmp_path / "out")]
    with open("/dev/full", "w") as full:
        r = subprocess.run([sys.executable, "-m", "pfscope.viewer_app.cli", *argv],
                           cwd=REPO, env=dict(os.environ, RERUN_ANALYTICS="0"), stdout=full,
                           stderr=subprocess.PIPE, text=True, timeout=120)
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    assert "cannot write" in r.stderr


@pytest.mark.parametrize("cmd,name", [("train-dbn", "m.pt"), ("train-classifier", "c.npz")])
def test_training_with_an_unwritable_out_fails_before_training(tmp_path, cmd, name):
    blocker = tmp_path / "file"
    blocker.write_text("a file, not a folder")
    t0 = time.time()
    r = cli(cmd, "synthetic", "--out", blocker / name, "--quiet")
    assert "cannot create output folder" in one_line_error(r)
    assert time.time() - t0 < 60
