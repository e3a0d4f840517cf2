"""The installed distribution's version (bottom layer: provenance records it).

Read when first asked for, not at import: ``importlib.metadata`` imports ``email`` and friends,
about 0.05 s that a command which records no version (``--help``, ``stability``) need not pay
(docs/startup.md). :func:`version` is the one reader (cached); ``haa_sym._version.__version__`` and
``haa_sym.__version__`` are the same string through PEP 562 ``__getattr__``."""
import functools


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


@functools.cache
def version() -> str:
    """The version string every output records (``haa-sym --version``, provenance, the
    schedule's CSV, the exported files): :func:`_version`, read once per process."""
    return _version()


def __getattr__(name: str):
    if name == "__version__":
        return version()
    raise AttributeError(f"module 'haa_sym._version' has no attribute {name!r}")
