"""`pfscope tune` on several sequences at once: the objective is the COMBINED score (counts
summed over the sequences, as TrackEval's COMBINED row and `pfscope eval` combine them), and
every sequence is reported apart beside the COMBINED rows."""

from __future__ import annotations

from dataclasses import asdict

import pytest

from pfscope.trackers.eval import combine
from pfscope.trackers.params import read_params_file
from pfscope.viewer_app.cli import main

optuna = pytest.importorskip("optuna", reason='pfscope tune needs the tune extra: '
                                              'pip install "pfscope[tune]"')


def _scene(seed: int, frames: int = 50, targets: int = 4, clutter: float = 2.0):
    from pfscope.trackers.data.synthetic import SceneConfig
    from pfscope.viewer_app.tune import SourceSpec

    cfg = SceneConfig(frames=frames, targets=targets, clutter=clutter, seed=seed)
    return SourceSpec(None, None, tuple(asdict(cfg).items()))


def _config(trials: int = 4, two: bool = True):
    from pfscope.viewer_app.tune import TuneConfig, TuneSequence

    more = (TuneSequence(_scene(5, targets=6, clutter=4.0), (1, 25), (26, 50), "B"),) \
        if two else ()
    return TuneConfig(source=_scene(1), tracker="mt", frames=(1, 25), holdout=(26, 50),
                      preset="paper", trials=trials, metric="mota", seed=0, batch=2, jobs=1,
                      eval_seeds=1, more=more, name="A")


def _score(spec, options: dict, frames=(1, 25)):
    """One sequence's full scores for the mt paper preset with ``options`` (seed 0)."""
    from pfscope.viewer_app.tune import EvalJob, evaluate_config

    r = evaluate_config(EvalJob(spec, "mt", "paper", tuple(options.items()), (0,), frames[0],
                                frames[1], (frames,), keep_scores=True))
    assert "error" not in r, r
    return r["scores"][0]["_scores"][0]


def test_the_objective_is_the_combined_score_of_the_sequences():
    from pfscope.viewer_app.tune import run_study

    res = run_study(_config())
    b = _config().more[0].source
    for t in res.trials:
        assert t["value"] is not None
        a_sc, b_sc = _score(_scene(1), t["options"]), _score(b, t["options"])
        # counts summed over the sequences, the ratio from the sums: not a mean of MOTAs
        assert t["value"] == pytest.approx(combine([a_sc, b_sc])["MOTA"])
        assert t["value"] == pytest.approx(
            1 - (a_sc["FP"] + b_sc["FP"] + a_sc["FN"] + b_sc["FN"] + a_sc["IDSW"]
                 + b_sc["IDSW"]) / (a_sc["GT"] + b_sc["GT"]))
    # the same study on A alone optimises A's score: a different objective
    alone = run_study(_config(two=False))
    assert [t["value"] for t in alone.trials] != [t["value"] for t in res.trials]
    assert alone.trials[0]["value"] == pytest.approx(_score(_scene(1), {})["MOTA"])


def test_each_sequence_is_reported_apart_and_combined():
    from pfscope.viewer_app.tune import format_table, run_study, tune_info

    res = run_study(_config())
    seqs = {r["sequence"] for r in res.table}
    assert seqs == {"A", "B", "COMBINED"}
    for who in ("start", "tuned"):
        for role in ("tuned on", "held out", "all (incl. tuned-on)"):
            rows = {r["sequence"]: r["mean"] for r in res.table
                    if r["who"] == who and r["role"] == role}
            assert set(rows) == {"A", "B", "COMBINED"}
            for k in ("FP", "FN", "IDSW"):       # COMBINED sums the counts
                assert rows["COMBINED"][k] == pytest.approx(rows["A"][k] + rows["B"][k])
    held = [r for r in res.table if r["sequence"] == "B" and r["role"] == "held out"]
    assert held and all(r["frames"] == (26, 50) for r in held)
    text = format_table(res)
    assert "COMBINED" in text and "\nA " in text and "\nB " in text
    info = tune_info(res, "A, B")
    assert info["sequences"] == ["A", "B"]
    assert set(info["scores"]["tuned"]) == {"A", "B", "COMBINED"}


def _write(tmp_path, name: str, seed: int):
    from pfscope.trackers.data.synthetic import SceneConfig, write_sequence

    return write_sequence(tmp_path / name, SceneConfig(frames=30, targets=4, seed=seed))


def test_tune_command_on_several_sequences(tmp_path, capsys):
    a, b = _write(tmp_path, "seqA", 1), _write(tmp_path, "seqB", 2)
    out = tmp_path / "best.toml"
    rc = main(["tune", str(a), str(b), "--tracker", "mt", "--frames", "1:15", "--trials", "3",
               "--jobs", "1", "--eval-seeds", "1", "--out", str(out), "--study-out",
               str(tmp_path / "study.rrd"), "--quiet"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    text = captured.out
    assert "COMBINED" in text and "seqA" in text and "seqB" in text
    pf = read_params_file(out)
    assert pf.info["sequences"] == ["seqA", "seqB"]
    assert pf.info["held_out_frames"] == ["16:30", "16:30"]
    assert set(pf.info["scores"]["start"]) == {"seqA", "seqB", "COMBINED"}


@pytest.mark.parametrize("extra, needle", [
    (["synthetic"], "not 'synthetic'"),
    (["--best-out", "x.rrd"], "record one sequence"),
    (["SAME"], "given twice"),
])
def test_several_sequences_refuse_in_one_line(tmp_path, capsys, extra, needle):
    a, b = _write(tmp_path, "seqA", 1), _write(tmp_path, "seqB", 2)
    extra = [str(a) if e == "SAME" else e for e in extra]
    srcs = [str(a), str(b)] + ([e for e in extra if not e.startswith("-") and e != "x.rrd"])
    opts = [e for e in extra if e.startswith("-") or e == "x.rrd"]
    rc = main(["tune", *srcs, "--tracker", "mt", "--trials", "2", "--out",
               str(tmp_path / "b.toml"), *opts, "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and needle in err and len(err.strip().splitlines()) == 1
