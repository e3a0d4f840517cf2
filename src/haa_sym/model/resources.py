"""Where the bundled data live: the source tree's ``model/`` and ``generated/``, or their copies
inside an installed package.

``model/`` (the actuator and paper files) and ``generated/`` (the C, header, ``.casadi`` files
and ``MANIFEST.json``) stay at the top of the source tree, the single source. ``pyproject.toml``
maps them into the package at build time (``[tool.setuptools.package-dir]``), so a wheel or a
non-editable install carries them as ``haa_sym/_model`` and ``haa_sym/_generated``, found with
:mod:`importlib.resources`. A source tree (an editable install, or ``PYTHONPATH=src``) reads the
top-level directories in place: setuptools' editable finder cannot import the mapped
directories, which have no ``__init__.py`` (and ``generated/`` must hold only what
``make derive`` writes).
"""
from __future__ import annotations

import importlib.resources
from pathlib import Path

__all__ = ["source_root", "data_dir", "remedy"]

_DIRS = ("model", "generated")


def source_root() -> Path | None:
    """The root of the source tree this package was loaded from, or None when installed.

    A source tree is recognised by its layout, not by a guess about how it was installed: the
    package lives in ``<root>/src/haa_sym`` and ``<root>/codegen/generate.py`` exists.
    """
    pkg = Path(__file__).resolve().parents[1]           # haa_sym/model/resources.py
    root = pkg.parents[1]
    if pkg.parent.name == "src" and (root / "codegen" / "generate.py").is_file():
        return root
    return None


def data_dir(name: str) -> Path:
    """The directory ``model`` or ``generated``: in the source tree, or inside the package."""
    if name not in _DIRS:
        raise ValueError(f"data directory {name!r}; allowed: {_DIRS}")
    root = source_root()
    if root is not None:
        return root / name
    # pip unpacks wheels, so the package's resources are plain files on disk.
    return Path(str(importlib.resources.files("haa_sym") / f"_{name}"))


def remedy() -> str:
    """What to do about generated code that is missing, stale or damaged, in this layout."""
    if source_root() is not None:
        return "run `make derive`"
    return ("the installed haa_sym package is damaged: reinstall it "
            "(pip install --force-reinstall haa_sym)")
