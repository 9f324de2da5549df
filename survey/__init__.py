"""indoormap survey stage: ingest survey walks, store them, simulate sites.

Kept import-light on purpose: ``localize`` imports :mod:`survey.errors` and must not pull in
pandas or scipy. Heavy submodules are imported by name (``from survey.trace_reader import ...``).
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("indoormap")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
