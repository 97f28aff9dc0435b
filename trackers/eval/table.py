"""A fixed-width text table of sequence scores, one row per tracker (for ``pfscope compare``)."""

from __future__ import annotations

import math
from typing import Mapping, Sequence

#: Columns shown by default, in order.
DEFAULT_COLUMNS = ("MOTA", "MOTP", "MODA", "MODP", "IDF1", "HOTA", "IDSW", "FP", "FN",
                   "OSPA", "GOSPA", "ME")

#: Scores printed with two decimals (pixels); counts print as integers; everything else is a
#: ratio printed with three decimals.
_PIXELS = {"OSPA", "GOSPA", "ME"}
_COUNTS = {"IDSW", "TP", "FP", "FN", "GT", "MT", "PT", "ML", "Frag", "IDTP", "IDFP", "IDFN",
           "num_frames", "num_gt_ids", "num_track_ids", "ignored_gt", "ignored_tracks",
           "track_rows_outside"}


def _cell(key: str, value) -> str:
    if value is None:
        return "-"
    v = float(value)
    if math.isnan(v):
        return "-"
    if key in _COUNTS:
        return f"{int(round(v))}"
    if key in _PIXELS:
        return f"{v:.2f}"
    return f"{v:.3f}"


def format_table(results: Mapping[str, Mapping[str, float]],
                 columns: Sequence[str] = DEFAULT_COLUMNS) -> str:
    """Rows = tracker names (in the order given), columns = score keys; right-aligned fixed
    width. A missing or nan value prints as ``-``. Returns the table without a trailing newline."""
    columns = list(columns)
    names = [str(n) for n in results]
    cells = [[_cell(c, r.get(c)) for c in columns] for r in results.values()]
    name_w = max([len("tracker")] + [len(n) for n in names])
    widths = [max([len(c)] + [len(row[i]) for row in cells]) for i, c in enumerate(columns)]
    lines = ["  ".join(["tracker".ljust(name_w)] + [c.rjust(w) for c, w in zip(columns, widths)])]
    lines.append("  ".join(["-" * name_w] + ["-" * w for w in widths]))
    for name, row in zip(names, cells):
        lines.append("  ".join([name.ljust(name_w)] + [v.rjust(w) for v, w in zip(row, widths)]))
    return "\n".join(lines)
