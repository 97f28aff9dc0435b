"""Documented parameters: one place for defaults, docs, paper references and option routing.

Every tracker's parameters are small frozen dataclasses whose fields carry their documentation
(``param(1500.0, "particles per target", paper="maggio2007 §4")``).  Dataclasses nest: a PHD
filter's parameters are its motion, likelihood, clutter, birth and resampling parts.  From that
one description come:

- :func:`describe` — rows (dotted name, default, doc, paper) for ``pfscope trackers``, the
  README and the recording's properties;
- :func:`with_options` — ``name=value`` options (``--set p_miss=0.2`` on the command line,
  keyword arguments in Python) routed to the field(s) that carry that name.  A leaf name
  (``p_miss``) sets every field of that name in the tree (the motion noise ``sigma_v`` is
  shared by the filter's motion model and the association); a dotted name
  (``filter.motion.sigma_v``) sets exactly one.  Strings are converted to the field's type, so
  the CLI and Python share the route; unknown names fail listing the known ones.
"""

from __future__ import annotations

import dataclasses
from dataclasses import field, fields, is_dataclass, replace
from typing import Any, Iterator


def param(default: Any, doc: str, *, paper: str | None = None) -> Any:
    """A dataclass field with its documentation (``metadata['doc']``) and, when the value comes
    from a paper, where (``metadata['paper']``, e.g. ``"maggio2007 §4"``)."""
    return field(default=default, metadata={"doc": doc, "paper": paper})


def part(factory: type, doc: str) -> Any:
    """A nested parameter dataclass (a *part*: motion, likelihood, birth ...)."""
    return field(default_factory=factory, metadata={"doc": doc, "paper": None})


def leaves(obj: Any, prefix: str = "") -> Iterator[tuple[str, dataclasses.Field, Any]]:
    """``(dotted name, field, value)`` for every scalar field of ``obj`` and its parts."""
    for f in fields(obj):
        value = getattr(obj, f.name)
        if is_dataclass(value):
            yield from leaves(value, f"{prefix}{f.name}.")
        else:
            yield f"{prefix}{f.name}", f, value


def describe(obj: Any) -> list[dict]:
    """One row per leaf field: ``name`` (dotted), ``default`` (the value in ``obj``), ``type``,
    ``doc`` and ``paper``."""
    rows = []
    for name, f, value in leaves(obj):
        rows.append({"name": name, "default": value, "type": _type_name(f),
                     "doc": f.metadata.get("doc", ""), "paper": f.metadata.get("paper")})
    return rows


def to_dict(obj: Any) -> dict:
    """Nested plain dict of the values (for ``config()`` and recordings)."""
    return dataclasses.asdict(obj)


def _type_name(f: dataclasses.Field) -> str:
    t = f.type
    return t if isinstance(t, str) else getattr(t, "__name__", str(t))


def _convert(value: Any, current: Any, name: str) -> Any:
    """Convert a CLI string to the type of the field's current value."""
    if not isinstance(value, str) or isinstance(current, str):
        if isinstance(current, float) and isinstance(value, int) and not isinstance(value, bool):
            return float(value)
        return value
    text = value.strip()
    try:
        if isinstance(current, bool):
            low = text.lower()
            if low in ("1", "true", "yes", "on"):
                return True
            if low in ("0", "false", "no", "off"):
                return False
            raise ValueError
        if isinstance(current, int):
            return int(text)
        if isinstance(current, float):
            return float(text)
    except ValueError:
        kind = type(current).__name__
        raise ValueError(f"option {name}={value!r}: expected {kind}") from None
    return text


def with_options(obj: Any, options: dict[str, Any]) -> Any:
    """A copy of ``obj`` with ``options`` applied (see the module docstring).  Validation in the
    dataclasses' ``__post_init__`` runs again, so a bad value fails here with its name."""
    known = {name: f for name, f, _ in leaves(obj)}
    for key, value in options.items():
        if key in known:
            targets = [key]
        else:
            targets = [n for n in known if n.rsplit(".", 1)[-1] == key]
        if not targets:
            names = sorted({n.rsplit(".", 1)[-1] for n in known})
            raise ValueError(f"unknown option {key!r}; known: {', '.join(names)}")
        for target in targets:
            obj = _set(obj, target.split("."), value, key)
    return obj


def _set(obj: Any, path: list[str], value: Any, shown: str) -> Any:
    head = path[0]
    current = getattr(obj, head)
    if len(path) == 1:
        new = _convert(value, current, shown)
    else:
        new = _set(current, path[1:], value, shown)
    try:
        return replace(obj, **{head: new})
    except (TypeError, ValueError) as e:
        raise ValueError(f"option {shown}={value!r}: {e}") from None


def parse_set(items: list[str] | None) -> dict[str, str]:
    """``["p_miss=0.2", "depth=30"]`` (repeated ``--set``) → ``{"p_miss": "0.2", "depth": "30"}``."""
    out: dict[str, str] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"--set {item!r}: expected NAME=VALUE")
        out[key.strip()] = value.strip()
    return out


__all__ = ["param", "part", "describe", "leaves", "with_options", "parse_set", "to_dict"]
