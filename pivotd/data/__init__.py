"""The files pivotd ships besides its code: config templates and their maps, RViz/Foxglove layouts (``config``),
the systemd unit and sysusers file (``systemd``).

They have one copy, at the repository root (``config/``, ``systemd/``); a wheel carries them as
``pivotd/data/config/`` and ``pivotd/data/systemd/`` (pyproject's ``package-dir`` mapping). :func:`data_dir`
finds them in either place: in the installed package through :mod:`importlib.resources`, else in the source
tree this package was imported from.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

from pivotd.compat import StrEnum
from pivotd.errors import PivotdError

if TYPE_CHECKING:
    from importlib.abc import Traversable


class DataDir(StrEnum):
    """A directory of shipped files (its name in the wheel and at the repository root)."""

    CONFIG = "config"
    SYSTEMD = "systemd"


def data_dir(kind: DataDir) -> Traversable:
    """The directory of shipped files ``kind``: ``pivotd/data/<kind>`` of an installed wheel, else ``<kind>/`` of
    the source tree (a checkout on ``PYTHONPATH`` or an editable install). Raises :class:`PivotdError` when
    neither exists (a broken install)."""
    packaged = resources.files(__name__) / str(kind)
    if packaged.is_dir():
        return packaged
    source = Path(__file__).resolve().parent.parent.parent / str(kind)
    if source.is_dir():
        return source
    raise PivotdError(f"pivotd's {kind} files are missing: neither {packaged} nor {source} exists (reinstall pivotd)")


def read_text(kind: DataDir, name: str) -> str:
    """The text of the shipped file ``name`` (a path relative to ``data_dir(kind)``, '/'-separated)."""
    return data_dir(kind).joinpath(*name.split("/")).read_text(encoding="utf-8")
