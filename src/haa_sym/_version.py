"""The installed distribution's version (bottom layer: provenance records it)."""


def _version() -> str:
    """``importlib.metadata``'s version of haa_sym; read from ``pyproject.toml`` when run from a
    source tree that was never installed (``PYTHONPATH=src``)."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("haa_sym")
    except PackageNotFoundError:
        import tomllib
        from pathlib import Path
        try:
            with open(Path(__file__).resolve().parents[2] / "pyproject.toml", "rb") as fh:
                return tomllib.load(fh)["project"]["version"]
        except (OSError, KeyError, tomllib.TOMLDecodeError):
            return "0+unknown"


__version__ = _version()
