"""The command line's documentation, generated from its argparse parsers.

    python -m pfscope.viewer_app.docgen            # rewrite README.md's generated blocks, docs/cli.md
    python -m pfscope.viewer_app.docgen --check    # exit 1 (and say which) when they are stale

The README holds the synopsis between ``<!-- cli-synopsis:begin -->`` and
``<!-- cli-synopsis:end -->``; ``docs/cli.md`` is the whole reference (every subcommand, every
option with its value, default and help).  Both are written only from :func:`build_parser`, so
an option added to a parser reaches the docs with one command, and ``tests/test_docs.py``
fails until it has.
"""

from __future__ import annotations

import argparse
import math
import sys
import textwrap
from pathlib import Path
from typing import Iterator, Optional

BEGIN = "<!-- cli-synopsis:begin (generated: python -m pfscope.viewer_app.docgen) -->"
END = "<!-- cli-synopsis:end -->"
WIDTH = 96


def _subparsers(ap: argparse.ArgumentParser) -> Iterator[tuple[str, argparse.ArgumentParser, str]]:
    for action in ap._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            for name, p in action.choices.items():
                yield name, p, helps.get(name, "")


_TYPE_NAMES = {"N or FIRST:LAST": "N|FIRST:LAST", "FIRST:LAST": "FIRST:LAST", "N": "N",
               "a positive integer": "N", "a non-negative integer": "N", "int": "N",
               "a positive number": "X", "a non-negative number": "X", "float": "X",
               "Path": "PATH"}


def _metavar(a: argparse.Action) -> str:
    if a.metavar is not None:
        return str(a.metavar)
    if a.choices is not None:
        return "|".join(map(str, a.choices))
    name = getattr(a.type, "__name__", "")
    if not a.option_strings:
        return a.dest.upper()
    if name in _TYPE_NAMES:
        return _TYPE_NAMES[name]
    if name.startswith("an ") or name.startswith("a "):   # _number(..., what="an IoU in (0, 1]")
        return "X"
    return a.dest.upper()


def _item(a: argparse.Action) -> str:
    """One action as the synopsis writes it, without the brackets of an optional one."""
    if not a.option_strings:
        return _metavar(a) + (" ..." if a.nargs in ("*", "+") else "")
    flag = max(a.option_strings, key=len)
    if a.nargs == 0:
        return flag
    rep = " ..." if isinstance(a, argparse._AppendAction) else ""
    return f"{flag} {_metavar(a)}{rep}"


def _optional(a: argparse.Action) -> bool:
    if a.option_strings:
        return not a.required
    return a.nargs in ("?", "*")


def _items(p: argparse.ArgumentParser) -> list[str]:
    groups = {id(a): g for g in p._mutually_exclusive_groups for a in g._group_actions}
    out: list[str] = []
    done: set = set()
    positionals = [a for a in p._actions if not a.option_strings]
    optionals = [a for a in p._actions if a.option_strings]
    for a in positionals + optionals:
        if isinstance(a, (argparse._HelpAction, argparse._VersionAction)) or id(a) in done:
            continue
        g = groups.get(id(a))
        if g is not None:
            members = [m for m in g._group_actions]
            done.update(id(m) for m in members)
            text = " | ".join(_item(m) for m in members)
            out.append(f"({text})" if g.required else f"[{text}]")
            continue
        done.add(id(a))
        out.append(f"[{_item(a)}]" if _optional(a) else _item(a))
    return out


def usage(name: str, p: argparse.ArgumentParser, width: int = WIDTH) -> str:
    """``pfscope NAME ...`` wrapped at ``width``, continuation lines under the first option."""
    head = f"pfscope {name} "
    lines, line = [], head
    for item in _items(p):
        if len(line) + len(item) > width and line.strip() != head.strip():
            lines.append(line.rstrip())
            line = " " * len(head)
        line += item + " "
    lines.append(line.rstrip())
    return "\n".join(lines)


def synopsis(ap: Optional[argparse.ArgumentParser] = None) -> str:
    """Every subcommand's usage, in the parser's order: the README's synopsis block."""
    if ap is None:
        from .cli import build_parser

        ap = build_parser()
    top = [_item(a) for a in ap._actions if a.option_strings
           and not isinstance(a, argparse._HelpAction)]
    lines = ["pfscope " + " | ".join(f"[{t}]" for t in top) + "   # and one of:"]
    lines += [usage(name, p) for name, p, _ in _subparsers(ap)]
    return "\n".join(lines)


def _default(a: argparse.Action) -> str:
    d = a.default
    if d is None or d is argparse.SUPPRESS or d is False or d == [] or a.nargs == 0:
        return ""
    if isinstance(d, float) and math.isinf(d):
        return "none" if d < 0 else "inf"
    if isinstance(d, Path):
        d = str(d)
    return f"`{d}`"


def _cell(text: str) -> str:
    """One line of markdown table text: ``|`` escaped, ``<source>`` kept from reading as HTML."""
    return (" ".join(str(text).split()).replace("|", "\\|")
            .replace("<", "&lt;").replace(">", "&gt;"))


def reference(ap: Optional[argparse.ArgumentParser] = None) -> str:
    """``docs/cli.md``: every subcommand with its usage and a table of its arguments."""
    if ap is None:
        from .cli import build_parser

        ap = build_parser()
    out = ["# Command line", "",
           "<!-- generated by `python -m pfscope.viewer_app.docgen` from the argparse parsers; "
           "do not edit by hand -->", "",
           _cell(ap.description or ""), "",
           "`pfscope --version` prints the version; `pfscope COMMAND --help` prints what this page "
           "says about COMMAND. Options that take frames all read `N` (the first N frames) or "
           "`FIRST:LAST` (the video's own frame numbers).", ""]
    for name, p, help_ in _subparsers(ap):
        out += [f"## {name}", "", _cell(help_[:1].upper() + help_[1:]) + ".", ""]
        if p.description and p.description.strip() != help_.strip():
            out += [textwrap.fill(_cell(p.description), 100), ""]
        out += ["```text", usage(name, p), "```", ""]
        rows = [a for a in p._actions if not isinstance(a, argparse._HelpAction)]
        if rows:
            out += ["| argument | value | default | what it does |", "|---|---|---|---|"]
            for a in rows:
                arg = ", ".join(f"`{o}`" for o in a.option_strings) or f"`{_metavar(a)}`"
                value = "" if a.nargs == 0 or not a.option_strings else f"`{_metavar(a)}`"
                help_text = "" if a.help is argparse.SUPPRESS else (a.help or "")
                if isinstance(a, argparse._AppendAction):
                    help_text += " (repeatable)"
                if a.required and a.option_strings:
                    help_text += " (required)"
                out.append(f"| {arg} | {_cell(value)} | {_cell(_default(a))} | "
                           f"{_cell(help_text)} |")
            out.append("")
    return "\n".join(out).rstrip() + "\n"


def readme_with_synopsis(readme: str, ap: Optional[argparse.ArgumentParser] = None) -> str:
    """``readme`` with the text between the synopsis markers replaced by :func:`synopsis`."""
    if BEGIN not in readme or END not in readme:
        raise ValueError(f"README.md has no {BEGIN} ... {END} block")
    head, rest = readme.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n```text\n{synopsis(ap)}\n```\n{END}{tail}"


TABS_BEGIN = "<!-- tabs:begin (generated: python -m pfscope.viewer_app.docgen) -->"
TABS_END = "<!-- tabs:end -->"


def readme_with_tabs(readme: str) -> str:
    """``readme`` with the text between the tab-table markers replaced by the layouts' own
    summary (:func:`pfscope.viewer_app.tabs.readme_summary`)."""
    from .tabs import readme_summary

    if TABS_BEGIN not in readme or TABS_END not in readme:
        raise ValueError(f"README.md has no {TABS_BEGIN} ... {TABS_END} block")
    head, rest = readme.split(TABS_BEGIN, 1)
    _, tail = rest.split(TABS_END, 1)
    return f"{head}{TABS_BEGIN}\n{readme_summary()}\n{TABS_END}{tail}"


def targets(root: Path) -> dict[Path, str]:
    """Each generated file and the text it must hold."""
    from .cli import build_parser

    ap = build_parser()
    readme = root / "README.md"
    return {readme: readme_with_tabs(readme_with_synopsis(readme.read_text(encoding="utf-8"),
                                                          ap)),
            root / "docs" / "cli.md": reference(ap)}


def main(argv: Optional[list[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pfscope.viewer_app.docgen",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true",
                        help="write nothing; exit 1 when a generated file is out of date")
    parser.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1],
                        help="the repository (default: the one this file is in)")
    args = parser.parse_args(argv)
    stale = []
    for path, text in targets(args.root).items():
        old = path.read_text(encoding="utf-8") if path.exists() else None
        if old != text:
            stale.append(path)
            if not args.check:
                path.parent.mkdir(parents=True, exist_ok=True)
                tmp = path.with_name(path.name + ".part")
                tmp.write_text(text, encoding="utf-8")
                tmp.replace(path)
    for path in stale:
        print(f"{'stale' if args.check else 'wrote'}: {path}", file=sys.stderr)
    return 1 if (stale and args.check) else 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
