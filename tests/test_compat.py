"""pivotd.compat.StrEnum behaves as Python 3.11's enum.StrEnum on every supported Python (3.10 builds its own)."""

from __future__ import annotations

import enum
import json

from pivotd.compat import StrEnum
from pivotd.daemon.states import DaemonState


class Colour(StrEnum):
    RED = "red"
    DARK_BLUE = enum.auto()


def test_members_are_their_values_as_strings():
    assert isinstance(Colour.RED, str) and Colour.RED == "red" and Colour("red") is Colour.RED
    assert str(Colour.RED) == "red" and f"{Colour.RED}" == "red" and f"{Colour.RED:>5}" == "  red"
    assert "%s" % Colour.RED == "red"  # noqa: UP031 (as logging formats its arguments)
    assert "-".join(Colour) == "red-dark_blue"
    assert json.dumps({"state": DaemonState.WAITING}) == '{"state": "waiting"}'


def test_auto_gives_the_lower_case_name():
    assert Colour.DARK_BLUE.value == "dark_blue"
