"""The wheel installs every package folder, and nothing at the top level but ``pfscope``."""

from __future__ import annotations

import tomllib

from conftest import REPO


def test_every_package_folder_is_listed_in_pyproject():
    cfg = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(cfg["packages"])
    mapping = cfg["package-dir"]
    found = set()
    # a folder mapped to a package of its own (viewer_app/_pfscope is `pfscope` itself) is
    # that package only, not also a subpackage of the folder holding it
    roots = {(REPO / folder).resolve() for folder in mapping.values()}
    for name, folder in mapping.items():
        root = REPO / folder
        for init in root.rglob("__init__.py"):
            inside = [p.resolve() for p in [init.parent, *init.parent.parents]
                      if p.resolve() != root.resolve() and root.resolve() in p.resolve().parents]
            if any(p in roots for p in inside):
                continue
            rel = init.parent.relative_to(root)
            found.add(".".join([name, *rel.parts]) if rel.parts else name)
    assert found == listed, f"missing from pyproject packages: {sorted(found - listed)}; " \
                            f"listed but absent: {sorted(listed - found)}"
    assert all(p.split(".")[0] == "pfscope" for p in listed)
