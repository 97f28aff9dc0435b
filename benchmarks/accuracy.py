"""Accuracy over the development set: every tracker × preset × seed on every sequence, one
table of MOTA, IDF1, HOTA, FP, FN, IDSW and OSPA per sequence and COMBINED.

    .venv/bin/python benchmarks/accuracy.py [--trackers phd,mt] [--presets practical,paper]
        [--seeds 0,1,2] [--sequences PETS09-S2L1,...] [--out runs/accuracy] [--workers N]
        [--bytetrack] [--json FILE] [--set NAME=VALUE ...]

The runs go through ``pfscope batch`` (same resume, same workers, ``--cluster`` if you pass it
through ``--batch-arg``), one batch per preset into ``OUT/<preset>``; the scoring through
``pfscope eval OUT/<preset> --gt DATA --json`` (counts summed over the sequences for
COMBINED, as TrackEval does).  Rows are means over the seeds; the spread (min–max of MOTA over
the seeds) is in the JSON.

``--bytetrack`` adds ByteTrack on the same detections as a reference (``supervision==0.26.1``,
``sv.ByteTrack()`` with its defaults, scores divided by the sequence's largest score when it
exceeds 1): install it beside pfscope without its OpenCV (``pip install --no-deps
supervision==0.26.1 && pip install defusedxml matplotlib pillow pyyaml requests tqdm``; its
``opencv-python`` dependency would shadow opencv-python-headless with OpenCV 5, which has no HOG).

The development set is every sequence with ``det/det.txt`` and ``gt/gt.txt`` under
``$PFSCOPE_DATA`` (default ``../shared/data``): PETS09-S2L1, PETS09-S3MF1 (frames), KITTI-13,
TUD-Stadtmitte (detections only: PHD-MT runs on blank frames, its colour cue off).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import EXIT_NO_DATA, data_roots, table, write_json  # noqa: E402

COLUMNS = ("MOTA", "IDF1", "HOTA", "FP", "FN", "IDSW", "OSPA")


def dev_sequences(names=None) -> list[Path]:
    for root in data_roots():
        if root.is_dir():
            seqs = sorted(p for p in root.iterdir()
                          if (p / "det" / "det.txt").is_file() and (p / "gt" / "gt.txt").is_file())
            if names:
                want = set(names)
                seqs = [p for p in seqs if p.name in want]
                missing = want - {p.name for p in seqs}
                if missing:
                    raise SystemExit(f"accuracy: not in {root}: {', '.join(sorted(missing))}")
            if seqs:
                return seqs
    raise SystemExit(EXIT_NO_DATA)


def pfscope(*args: str) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).with_name("pfscope")
    cmd = [str(exe) if exe.exists() else "pfscope", *args]
    return subprocess.run(cmd, capture_output=True, text=True)


def bytetrack_tracks(seqs: list[Path], out: Path) -> None:
    """ByteTrack (supervision's defaults) on each sequence's detections → OUT/SEQ-bytetrack-seed0.txt."""
    import supervision as sv

    from pfscope.trackers.data.motio import write_mot
    from pfscope.trackers.data.sources import open_source

    out.mkdir(parents=True, exist_ok=True)
    for seq in seqs:
        src = open_source(seq)
        det = src.det
        smax = float(det.score.max()) if len(det) else 1.0
        scale = smax if smax > 1.0 else 1.0
        bt = sv.ByteTrack()
        F, I, B = [], [], []
        for f in range(1, src.length + 1):
            d = det.detections(f)
            b = d.boxes
            xyxy = np.c_[b[:, :2], b[:, :2] + b[:, 2:]] if len(b) else np.zeros((0, 4))
            res = bt.update_with_detections(sv.Detections(
                xyxy=xyxy.astype(float), confidence=(d.scores / scale).astype(float),
                class_id=np.zeros(len(b), int)))
            if len(res):
                F.append(np.full(len(res), f))
                I.append(res.tracker_id.astype(np.int64))
                B.append(np.c_[res.xyxy[:, :2], res.xyxy[:, 2:] - res.xyxy[:, :2]])
        cat = (lambda xs, shape: np.concatenate(xs) if xs else np.zeros(shape))
        write_mot(out / f"{seq.name}-bytetrack-seed0.txt", "tracks", cat(F, (0,)),
                  cat(I, (0,)), cat(B, (0, 4)))


def scores_of(out: Path, gt_root: Path) -> dict:
    r = pfscope("eval", str(out), "--gt", str(gt_root), "--json")
    if r.returncode != 0:
        raise SystemExit(f"accuracy: pfscope eval {out} failed: {r.stderr.strip()[-300:]}")
    return json.loads(r.stdout)


def by_lane(runs: dict) -> dict:
    """{"phd-seed0": {seq: scores}} → {"phd": {seq: [scores per seed]}}."""
    out: dict = {}
    for run, table_ in runs.items():
        lane = run.rsplit("-seed", 1)[0]
        for seq, sc in table_.items():
            out.setdefault(lane, {}).setdefault(seq, []).append(sc)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trackers", default="phd,mt")
    ap.add_argument("--presets", default="practical,paper")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--sequences", default=None, help="comma-separated names (default: all)")
    ap.add_argument("--out", default="runs/accuracy")
    ap.add_argument("--workers", default=None)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--bytetrack", action="store_true")
    ap.add_argument("--force", action="store_true", help="re-run finished runs")
    ap.add_argument("--json", default=None, help="write every number here")
    a = ap.parse_args(argv)
    seqs = dev_sequences(a.sequences.split(",") if a.sequences else None)
    gt_root = seqs[0].parent
    if a.sequences:  # score only the chosen ones: a folder of links to them
        gt_root = Path(a.out) / "_sequences"
        gt_root.mkdir(parents=True, exist_ok=True)
        for s in seqs:
            link = gt_root / s.name
            if not link.exists():
                link.symlink_to(s.resolve())
    results: dict = {}
    for preset in a.presets.split(","):
        out = Path(a.out) / preset
        args = ["batch", "--sources", ",".join(str(s) for s in seqs), "--trackers", a.trackers,
                "--seeds", a.seeds, "--preset", preset, "--level", "tracks", "--out", str(out),
                "--quiet"]
        args += [x for kv in a.set for x in ("--set", kv)]
        args += ["--workers", a.workers] if a.workers else []
        args += ["--force"] if a.force else []
        print(f"accuracy: pfscope {' '.join(args)}", file=sys.stderr)
        r = pfscope(*args)
        if r.returncode != 0:
            print(r.stdout[-2000:], r.stderr[-2000:], file=sys.stderr)
            return 1
        for lane, per in by_lane(scores_of(out, gt_root)).items():
            results[f"{lane} ({preset})"] = per
    if a.bytetrack:
        out = Path(a.out) / "bytetrack"
        bytetrack_tracks(seqs, out)
        results.update({f"{k} (supervision 0.26.1)": v
                        for k, v in by_lane(scores_of(out, gt_root)).items()})
    names = [s.name for s in seqs] + ["COMBINED"]
    rows = []
    summary: dict = {}
    for label, per in results.items():
        for seq in names:
            runs = per.get(seq, [])
            if not runs:
                continue
            mean = {k: float(np.mean([r[k] for r in runs])) for k in COLUMNS}
            mota = [r["MOTA"] for r in runs]
            summary.setdefault(label, {})[seq] = dict(mean, seeds=len(runs),
                                                      MOTA_min=min(mota), MOTA_max=max(mota))
            rows.append([label, seq] + [f"{mean[k]:.3f}" if k in ("MOTA", "IDF1", "HOTA")
                                        else f"{mean[k]:.1f}" for k in COLUMNS])
    print(table(["tracker (preset)", "sequence", *COLUMNS], rows))
    print(f"\nmeans over seeds {a.seeds}; COMBINED sums the counts over "
          f"{len(seqs)} sequences; py-motmetrics-equivalent MOT15 convention")
    write_json(a.json, {"command": " ".join(sys.argv), "results": summary})
    return 0


if __name__ == "__main__":
    sys.exit(main())
