"""Standard-library names newer than the oldest supported Python (3.10), in one place.

:class:`StrEnum` is :class:`enum.StrEnum` on Python 3.11 and newer; on 3.10 it is the same contract built from
``str`` and :class:`enum.Enum`: members are strings equal to their values, and ``str()``, ``format()`` and
f-strings give the value (not ``Class.MEMBER``).
"""

from __future__ import annotations

import enum
import sys

__all__ = ["StrEnum"]

if sys.version_info >= (3, 11):
    from enum import StrEnum
else:

    class StrEnum(str, enum.Enum):
        """Enum whose members are strings (Python 3.11's :class:`enum.StrEnum`)."""

        __str__ = str.__str__
        __format__ = str.__format__

        @staticmethod
        def _generate_next_value_(name: str, start: int, count: int, last_values: list[str]) -> str:
            """``auto()`` gives the member's name in lower case, as 3.11 does."""
            return name.lower()
