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
  the CLI and Python share the route; unknown names fail listing the known ones;
- :func:`read_params_file` / :func:`write_params_file` — a parameters file (TOML) that
  ``pfscope record --params FILE`` reads and ``pfscope tune`` writes::

      tracker = "phd"            # optional: the tracker these are for
      preset = "paper"           # optional: the preset they start from
      [params.filter.likelihood] # nested tables follow the parts (or "dotted.name" = v,
      p_miss = 0.12              # or a leaf name alone, routed as --set routes it)
      [tune]                     # optional, informational: how the values were found

  A bad key or value fails with one line naming the file and the key.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from dataclasses import field, fields, is_dataclass, replace
from pathlib import Path
from typing import Any, Iterator, Optional

from .errors import did_you_mean


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
    before = {name: v for name, _, v in leaves(obj)}
    asked: dict[str, str] = {}
    for key, value in options.items():
        if key in known:
            targets = [key]
        else:
            targets = [n for n in known if n.rsplit(".", 1)[-1] == key]
        if not targets:
            names = sorted({n.rsplit(".", 1)[-1] for n in known} | set(known))
            raise ValueError(f"unknown parameter {key!r}{did_you_mean(key, names)}; "
                             f"`pfscope trackers` lists all {len(known)}")
        for target in targets:
            obj = _set(obj, target.split("."), value, key)
            asked[target] = key
    _refuse_silent(obj, asked, before)
    return obj


def derived_from(obj: Any) -> dict:
    """``{dotted field: why}``: the fields a setting cannot change in ``obj`` as it stands (a
    params class declares them with ``derived_from()``: e.g. the per-frame fields the
    ``practical`` preset derives from its per-second ``rate.*`` settings)."""
    fn = getattr(obj, "derived_from", None)
    return dict(fn()) if callable(fn) else {}


def _refuse_silent(obj: Any, asked: dict, before: dict) -> None:
    """No silent settings: an option that changed a field the result never reads (see
    :func:`derived_from`) is refused with one line naming what to set instead.  Writing a
    field's current value (a parameters file lists every field) is not a change."""
    if not asked:
        return
    ignored = derived_from(obj)
    after = {name: v for name, _, v in leaves(obj)}
    for target, key in asked.items():
        if target in ignored and after[target] != before.get(target):
            raise ValueError(f"option {key}={after[target]!r}: {target} is {ignored[target]}")


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


# ------------------------------------------------------------------ parameters files (TOML)

#: Top-level keys of a parameters file.
PARAMS_FILE_KEYS = ("tracker", "preset", "params", "tune")


@dataclasses.dataclass(frozen=True)
class ParamsFile:
    """A parameters file read by :func:`read_params_file`: ``options`` maps dotted (or leaf)
    names to typed values, in the file's order; ``info`` is its ``[tune]`` table."""

    path: Path
    tracker: Optional[str] = None
    preset: Optional[str] = None
    options: dict = dataclasses.field(default_factory=dict)
    info: dict = dataclasses.field(default_factory=dict)

    def check(self, params: Any) -> Any:
        """``params`` with the file's options applied; a bad key or value raises ValueError
        naming the file and the key."""
        return apply_file_options(params, self.options, self.path)


def _load_toml(text: str) -> dict:
    try:
        import tomllib
    except ImportError:  # Python 3.10
        try:
            import tomli as tomllib  # type: ignore[no-redef]
        except ImportError:
            raise ValueError("reading TOML on Python 3.10 needs tomli: pip install tomli") \
                from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"not valid TOML ({e})") from None


def _flatten(table: dict, prefix: str, where: str) -> dict:
    out: dict = {}
    for key, value in table.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flatten(value, f"{name}.", where))
        elif isinstance(value, bool) or isinstance(value, (int, float, str)):
            out[name] = value
        else:
            raise ValueError(f"{where}: {name}: expected a number, a boolean or a string, "
                             f"got {type(value).__name__}")
    return out


def read_params_file(path: str | os.PathLike) -> ParamsFile:
    """Read a parameters file (module docstring).  Problems raise ValueError with one line
    naming the file (and the key): missing file, bad TOML, unknown top-level key, a value that
    is not a number, boolean or string.  The names themselves are checked against a tracker by
    :meth:`ParamsFile.check`."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ValueError(f"{path}: no such parameters file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    try:
        data = _load_toml(text)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
    for key in data:
        if key not in PARAMS_FILE_KEYS:
            raise ValueError(f"{path}: unknown key {key!r} (a parameters file has "
                             f"tracker, preset, [params] and [tune])")
    for key in ("tracker", "preset"):
        if key in data and not isinstance(data[key], str):
            raise ValueError(f"{path}: {key}: expected a string, got {data[key]!r}")
    params = data.get("params", {})
    if not isinstance(params, dict):
        raise ValueError(f"{path}: params: expected a table ([params])")
    info = data.get("tune", {})
    if not isinstance(info, dict):
        raise ValueError(f"{path}: tune: expected a table ([tune])")
    return ParamsFile(path, data.get("tracker"), data.get("preset"),
                      _flatten(params, "", str(path)), info)


def apply_file_options(obj: Any, options: dict, where: Any) -> Any:
    """``obj`` with ``options`` (typed values from a file) applied one by one, so that an
    unknown name, a value of the wrong type or one the dataclass refuses raises ValueError
    naming ``where`` and the key."""
    known = {name: f for name, f, _ in leaves(obj)}
    current = {name: v for name, _, v in leaves(obj)}
    for key, value in options.items():
        targets = [key] if key in known else [n for n in known if n.rsplit(".", 1)[-1] == key]
        if not targets:
            names = sorted({n.rsplit(".", 1)[-1] for n in known} | set(known))
            raise ValueError(f"{where}: unknown parameter {key!r}{did_you_mean(key, names)}; "
                             f"`pfscope trackers` lists them")
        for t in targets:
            cur = current[t]
            ok = (isinstance(value, str) or
                  (isinstance(cur, bool) and isinstance(value, bool)) or
                  (not isinstance(cur, bool) and isinstance(cur, int)
                   and isinstance(value, int) and not isinstance(value, bool)) or
                  (isinstance(cur, float) and isinstance(value, (int, float))
                   and not isinstance(value, bool)) or
                  not isinstance(cur, (bool, int, float, str)))
            if not ok:
                raise ValueError(f"{where}: {key} = {value!r}: expected "
                                 f"{type(cur).__name__}")
        try:
            obj = with_options(obj, {key: value})
        except ValueError as e:
            msg = str(e)
            prefix = f"option {key}={value!r}: "
            msg = msg[len(prefix):] if msg.startswith(prefix) else msg
            raise ValueError(f"{where}: {key} = {value!r}: {msg}") from None
    return obj


_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def _toml_key(key: str) -> str:
    return key if _BARE_KEY.match(key) else _toml_str(key)


def _toml_str(text: str) -> str:
    import json

    return json.dumps(text, ensure_ascii=False)  # JSON's escapes are valid TOML basic strings


def toml_value(value: Any) -> str:
    """One TOML value: bool, int, float (``inf``, ``nan`` too), string, or a flat list."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return _toml_str(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} as TOML")


def to_toml(data: dict, *, header: str = "", comments: Optional[dict] = None) -> str:
    """A small TOML document from a nested dict of scalars (and flat lists).  ``comments``
    maps dotted key paths to an end-of-line comment; ``header`` lines become ``#`` comments."""
    comments = comments or {}
    lines = [f"# {ln}".rstrip() for ln in header.splitlines()] if header else []

    def emit(table: dict, path: list[str]) -> None:
        scalars = [(k, v) for k, v in table.items()
                   if not isinstance(v, dict) and v is not None]  # TOML has no null: unset
        subs = [(k, v) for k, v in table.items() if isinstance(v, dict)]
        if path and (scalars or not subs):
            if lines:
                lines.append("")
            lines.append("[" + ".".join(_toml_key(p) for p in path) + "]")
        for k, v in scalars:
            note = comments.get(".".join(path + [k]))
            lines.append(f"{_toml_key(k)} = {toml_value(v)}" + (f"  # {note}" if note else ""))
        for k, v in subs:
            emit(v, path + [k])

    emit(data, [])
    return "\n".join(lines) + "\n"


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` under a temporary name beside ``path`` and rename it into place, so a
    reader never sees half a file."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.part")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def write_params_file(path: str | os.PathLike, tracker: str, params: Any, *,
                      preset: Optional[str] = None, info: Optional[dict] = None,
                      header: str = "", marked: Optional[dict] = None) -> Path:
    """Write every parameter of ``params`` (nested tables) for ``tracker`` as a parameters file
    (atomically).  ``marked``: dotted name → comment put beside that value (``tuned``);
    ``info``: the ``[tune]`` table."""
    data: dict = {"tracker": tracker}
    if preset:
        data["preset"] = preset
    data["params"] = to_dict(params)
    if info:
        data["tune"] = info
    comments = {f"params.{k}": v for k, v in (marked or {}).items()}
    return write_text_atomic(path, to_toml(data, header=header, comments=comments))


__all__ = ["param", "part", "describe", "leaves", "with_options", "derived_from", "parse_set", "to_dict",
           "ParamsFile", "read_params_file", "apply_file_options", "write_params_file",
           "to_toml", "toml_value", "write_text_atomic"]
