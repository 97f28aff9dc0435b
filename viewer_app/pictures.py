"""The README's pictures: each tracker on PETS09-S2L1, recorded and snapshotted headlessly.

    python -m pfscope.viewer_app.pictures [--data ../shared/data] [--out docs] [--frame 100]

For each registered tracker among phd, mt, dlpf and dbn-phd: record PETS09-S2L1 frames
1..FRAME+10 at ``--level particles`` into a temporary folder, snapshot frame FRAME on the
tracker's particle tab with :func:`pfscope.viewer_app.snapshot.snapshot`, and write a small
JPEG ``docs/viewer-pets-<tracker>.jpg`` (1280 px wide).  A tracker that cannot run here (e.g.
dbn-phd without its trained model) is reported and skipped.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

#: tracker -> the video tab to show (the one with its particle clouds)
TABS = {"phd": "Particles", "mt": "Association", "dlpf": "Children", "dbn-phd": "Update"}


def make_pictures(data: Path, out: Path, frame: int = 100, width: int = 1280,
                  trackers=None) -> list[Path]:
    import cv2

    from pfscope.trackers.api import registry

    from .api import record
    from .snapshot import snapshot

    seq = data / "PETS09-S2L1"
    out.mkdir(parents=True, exist_ok=True)
    names = [n for n in (trackers or TABS) if n in registry()]
    written = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            rrd = Path(tmp) / f"{name}.rrd"
            try:
                record(seq, tracker=name, out=rrd, level="particles", frames=frame + 10,
                       progress=True)
                png = snapshot(rrd, Path(tmp) / f"{name}.png", frame=frame, tab=TABS.get(name))
            except Exception as e:  # noqa: BLE001 - report and go on with the others
                print(f"pictures: {name}: skipped ({type(e).__name__}: {e})", file=sys.stderr)
                continue
            img = cv2.imread(str(png))
            h = int(round(img.shape[0] * width / img.shape[1]))
            img = cv2.resize(img, (width, h), interpolation=cv2.INTER_AREA)
            dst = out / f"viewer-pets-{name}.jpg"
            cv2.imwrite(str(dst), img, [cv2.IMWRITE_JPEG_QUALITY, 82])
            print(f"pictures: wrote {dst}", file=sys.stderr)
            written.append(dst)
    return written


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m pfscope.viewer_app.pictures",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=Path(os.environ.get("PFSCOPE_DATA",
                                                                      "../shared/data")))
    ap.add_argument("--out", type=Path, default=Path("docs"))
    ap.add_argument("--frame", type=int, default=100)
    ap.add_argument("--trackers", default=None, help="comma-separated (default: all four)")
    args = ap.parse_args(argv)
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    names = args.trackers.split(",") if args.trackers else None
    return 0 if make_pictures(args.data, args.out, args.frame, trackers=names) else 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
