"""``pfscope train-classifier``: DLPF's intersection-kernel SVM (jung2013 §2.1, Maji et al.
2008) from a sequence's ground truth.  ``add_parser(sub)`` adds the subcommand to pfscope's
argparse sub-parsers; ``cmd_train_classifier(args)`` runs it (bad input raises the one-line
:class:`~pfscope.trackers.errors.InputError` that ``pfscope``'s main prints)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from pfscope.trackers.errors import InputError


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "train-classifier",
        help="train DLPF's intersection-kernel SVM (jung2013) on a sequence's ground truth",
        description="Train the intersection-kernel SVM on HOG windows of DLPF (jung2013 §2.1, "
                    "Maji et al. 2008 fast lookup-table evaluation).  Positives: the ground-"
                    "truth people of the chosen frames; negatives: random background windows, "
                    "windows shifted or rescaled off a person, and hard negatives (background "
                    "windows the first model scores positive; then it is retrained).  The last "
                    "--holdout fraction of the frames is held out and the accuracy and ROC AUC "
                    "there are reported.  Use the model with "
                    "'pfscope record SOURCE --tracker dlpf --classifier MODEL'.  Never evaluate "
                    "on the frames it was trained on (PETS09-S2L1: train on 1:400, report on "
                    "401-795).")
    p.add_argument("source", help="sequence with ground truth (MOT layout: img1/, gt/gt.txt)")
    p.add_argument("--out", type=Path, required=True, help="model file to write (.npz)")
    from .cli import FRAMES

    p.add_argument("--frames", type=FRAMES, default=None, metavar="N|FIRST:LAST",
                   help="frames to train on, e.g. 1:400 (held-out split included); default: "
                        "the first half of the sequence")
    p.add_argument("--holdout", type=float, default=0.2,
                   help="fraction of the frames (the last ones) held out for the reported "
                        "accuracy (default 0.2; 0: none)")
    p.add_argument("--stride", type=int, default=8, help="sample every N-th frame (default 8)")
    p.add_argument("--negatives", type=int, default=10,
                   help="random background windows per sampled frame (default 10)")
    p.add_argument("--hard", type=int, default=600,
                   help="at most this many hard negatives for the second round (default 600; "
                        "0: one round only)")
    p.add_argument("--C", dest="C", type=float, default=1.0, help="SVM C (default 1)")
    p.add_argument("--bins", type=int, default=64,
                   help="lookup-table samples per dimension (default 64)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the negative windows")
    p.add_argument("--force", action="store_true", help="overwrite --out")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    return p


def _frame_range(frames, length):
    """``--frames`` as parsed (N or (FIRST, LAST)); default: the first half of the sequence."""
    if frames is None and length:
        return 1, max(1, int(length) // 2)
    from .cli import frames_within

    return frames_within(frames, length, "source")


def cmd_train_classifier(args) -> int:
    import numpy as np
    from pfscope.trackers.data.sources import open_source
    from pfscope.trackers.dbn.model import roc_auc
    from pfscope.trackers.dlpf.iksvm import (
        IKSVMClassifier,
        collect_samples,
        hard_negatives,
        train_iksvm,
    )

    out = Path(args.out)
    if out.suffix != ".npz":
        raise InputError(f"--out {out}: use a .npz file name")
    from pfscope.trackers.outputs import check_output

    # before training: an unwritable --out must not cost the training run
    check_output(out, args.force, "classifier model")
    if not 0.0 <= args.holdout < 1.0:
        raise InputError(f"--holdout must be in [0, 1), got {args.holdout}")
    if args.stride < 1 or args.negatives < 0 or args.hard < 0 or args.bins < 2 or args.C <= 0:
        raise InputError("need --stride >= 1, --negatives >= 0, --hard >= 0, --bins >= 2, --C > 0")
    try:
        src = open_source(args.source)
    except (OSError, ValueError) as e:
        raise InputError(f"{args.source}: {str(e).splitlines()[0] if str(e) else e}") from None
    lo, hi = _frame_range(args.frames, getattr(src, "length", None))
    cut = hi - int(round(args.holdout * (hi - lo + 1)))
    t0 = time.perf_counter()
    last = [0.0]

    def say(msg: str) -> None:
        if not args.quiet:
            print(f"train-classifier: {msg} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr,
                  flush=True)

    def progress(phase, i, n):
        now = time.perf_counter()
        if i == n or now - last[0] > 2.0:
            last[0] = now
            say(f"{phase} frame {i}/{n}")

    s = collect_samples(src, range(lo, hi + 1), stride=args.stride, negatives=args.negatives,
                        seed=args.seed, progress=progress)
    train = s.frame <= cut
    hold = ~train
    if s.y[train].min() == s.y[train].max():
        raise InputError(f"{args.source} frames {lo}-{cut}: need both people and background "
                         "windows to train on")
    say(f"{int(train.sum())} training samples ({int(s.y[train].sum())} people), "
        f"{int(hold.sum())} held out; training the intersection-kernel SVM")
    tables = train_iksvm(s.X[train], s.y[train], C=args.C, bins=args.bins)
    X, y = s.X[train], s.y[train]
    n_hard = 0
    if args.hard:
        hn = hard_negatives(src, range(lo, cut + 1), tables, stride=args.stride,
                            limit=args.hard, seed=args.seed + 1, progress=progress)
        n_hard = len(hn.X)
        if n_hard:
            say(f"{n_hard} hard negatives; retraining")
            X, y = np.concatenate([X, hn.X]), np.concatenate([y, hn.y])
            tables = train_iksvm(X, y, C=args.C, bins=args.bins)
    info = {"source": getattr(src, "name", str(args.source)), "frames": f"{lo}-{cut}",
            "held_out_frames": f"{cut + 1}-{hi}" if hold.any() else "",
            "stride": args.stride, "samples": len(y), "people": int(y.sum()),
            "hard_negatives": n_hard, "support_vectors": len(tables.sv), "C": args.C,
            "bins": args.bins, "seed": args.seed,
            "train_accuracy": float(((tables.decision(X) > 0) == (y > 0)).mean())}
    if hold.any():
        d = tables.decision(s.X[hold])
        yh = s.y[hold] > 0
        info.update(holdout=int(hold.sum()), holdout_people=int(yh.sum()),
                    holdout_accuracy=float(((d > 0) == yh).mean()),
                    holdout_auc=roc_auc(d, yh),
                    lookup_max_error=float(np.abs(d[:200] - tables.exact(s.X[hold][:200])).max()))
    out.parent.mkdir(parents=True, exist_ok=True)
    IKSVMClassifier(tables, info).save(str(out))
    print(f"trained on {info['samples']} samples ({info['people']} people, {n_hard} hard "
          f"negatives) from {info['source']} frames {lo}-{cut} (every {args.stride}th): "
          f"{info['support_vectors']} support vectors, training accuracy "
          f"{info['train_accuracy']:.3f}, {time.perf_counter() - t0:.0f} s")
    if hold.any():
        print(f"held out frames {cut + 1}-{hi}: {info['holdout']} samples "
              f"({info['holdout_people']} people): accuracy {info['holdout_accuracy']:.3f}  "
              f"ROC AUC {info['holdout_auc']:.3f}  (lookup vs exact kernel: max "
              f"|difference| {info['lookup_max_error']:.2g})")
    print(f"wrote {out} ({out.stat().st_size / 1024:.0f} KB)")
    print(f"use it with:  pfscope record SOURCE --tracker dlpf --set model={out}  (evaluate "
          f"only on frames after {hi})")
    return 0


__all__ = ["add_parser", "cmd_train_classifier"]
