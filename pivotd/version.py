"""The installed pivotd's version: the package metadata's, else :data:`pivotd.__version__` (a source tree)."""

from __future__ import annotations

import functools
import importlib.metadata

import pivotd


@functools.cache
def version() -> str:
    """The version string of this pivotd (``pivotd --version``, the ready line, the status document)."""
    try:
        return importlib.metadata.version("pivotd")
    except importlib.metadata.PackageNotFoundError:
        return pivotd.__version__
