"""MkDocs hook (mkdocs.yml ``hooks``): let mkdocstrings find ``covswarm`` without importing it.

The repository's folders install as ``covswarm.<folder>`` through pyproject's
``package-dir``, a mapping that a static source finder (griffe, under mkdocstrings) cannot
follow, and griffe's import fallback does not handle the editable install's namespace
package. So before the build this writes ``.api-src/covswarm/<folder>`` symlinks to the
folders that pyproject maps (mkdocs.yml points the Python handler's ``paths`` there).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ROOT / ".api-src"


def on_startup(**kwargs: Any) -> None:
    """Write SOURCES/covswarm/<folder> -> <folder> for every package pyproject maps."""
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    mapping = pyproject["tool"]["setuptools"]["package-dir"]
    package = SOURCES / "covswarm"
    package.mkdir(parents=True, exist_ok=True)
    for name, folder in mapping.items():
        link = package / name.removeprefix("covswarm.")
        if not link.is_symlink():
            link.symlink_to(ROOT / folder, target_is_directory=True)
