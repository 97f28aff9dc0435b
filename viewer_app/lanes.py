"""Lane specs for ``compare`` / ``record`` / ``batch``: a tracker name with optional parameter
overrides, ``phd``, ``phd[p_miss=0.2]``, ``phd[p_miss=0.2;depth=30]`` (``;`` or ``,`` inside the
brackets).

A lane's name is its spec made safe for a Rerun entity path (letters, digits, ``_ . -``; runs
of anything else become one ``-``): ``phd[p_miss=0.2]`` → ``phd-p_miss-0.2``.  Each lane gets its
own root (``/phd-p_miss-0.2/video/tracks`` ...) and its own stage slots.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from pfscope.trackers.errors import InputError


@dataclass(frozen=True)
class Lane:
    spec: str                 # as written: "phd[p_miss=0.2]"
    tracker: str              # registry name: "phd"
    options: dict = field(default_factory=dict)   # {"p_miss": "0.2"}

    @property
    def name(self) -> str:
        return lane_name(self.spec)


def lane_name(spec: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", spec.strip()).strip("-") or "lane"


def split_specs(text: str) -> list[str]:
    """``"phd,phd[p_miss=0.2,depth=3],mt"`` → three specs (commas inside brackets kept)."""
    out, depth, cur = [], 0, []
    for ch in text:
        if ch == "[":
            depth += 1
        elif ch == "]":
            depth -= 1
            if depth < 0:
                raise InputError(f"--trackers {text!r}: unbalanced ']'")
        if ch == "," and depth == 0:
            out.append("".join(cur).strip())
            cur = []
        else:
            cur.append(ch)
    if depth:
        raise InputError(f"--trackers {text!r}: unbalanced '['")
    out.append("".join(cur).strip())
    return [s for s in out if s]


def parse_lane(spec: str) -> Lane:
    m = re.fullmatch(r"\s*([A-Za-z0-9_.-]+)\s*(?:\[(.*)\])?\s*", spec)
    if not m:
        raise InputError(f"tracker spec {spec!r}: expected NAME or NAME[key=value;...]")
    name, inner = m.group(1), m.group(2)
    opts: dict = {}
    for item in re.split(r"[;,]", inner or ""):
        if not item.strip():
            continue
        k, eq, v = item.partition("=")
        if not eq or not k.strip():
            raise InputError(f"tracker spec {spec!r}: {item.strip()!r} is not key=value")
        opts[k.strip()] = v.strip()
    return Lane(spec.strip(), name, opts)


def parse_lanes(text_or_list) -> list[Lane]:
    specs = split_specs(text_or_list) if isinstance(text_or_list, str) else list(text_or_list)
    lanes = [parse_lane(s) if isinstance(s, str) else s for s in specs]
    names = [ln.name for ln in lanes]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError(f"tracker listed twice: {', '.join(dup)}")
    return lanes


__all__ = ["Lane", "lane_name", "split_specs", "parse_lane", "parse_lanes"]
