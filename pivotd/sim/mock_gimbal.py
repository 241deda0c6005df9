"""The gimbal simulator's entry point (``tools/mock_gimbal``, the ``pivotd-mock-gimbal`` console script):
``--protocol pivot`` (default; pivotd's serial protocol on a pty / TCP port / serial port, see
pivotd/firmware_proto/mock_server.py), ``--protocol mavlink`` (a MAVLink gimbal manager on UDP, see
pivotd/sim/mavlink_server.py) or ``--protocol dynamixel`` (two DYNAMIXEL servos on a pty, see
pivotd/sim/dynamixel_server.py). ``--protocol X --help`` lists the options of each."""

from __future__ import annotations

import sys

PROTOCOLS = ("pivot", "mavlink", "dynamixel")


def split_protocol(argv: list[str]) -> tuple[str, list[str]]:
    """The ``--protocol`` value (default pivot) and the remaining arguments."""
    rest, protocol, i = [], "pivot", 0
    while i < len(argv):
        arg = argv[i]
        if arg == "--protocol" and i + 1 < len(argv):
            protocol, i = argv[i + 1], i + 2
            continue
        if arg.startswith("--protocol="):
            protocol = arg.split("=", 1)[1]
        else:
            rest.append(arg)
        i += 1
    if protocol not in PROTOCOLS:
        raise SystemExit(f"mock_gimbal: error: --protocol must be one of {', '.join(PROTOCOLS)}; got {protocol!r}")
    return protocol, rest


def main(argv: list[str] | None = None) -> int:
    """Run the simulator of ``--protocol`` with the other arguments; its exit code."""
    protocol, args = split_protocol(list(sys.argv[1:] if argv is None else argv))
    if protocol == "mavlink":
        from pivotd.sim.mavlink_server import main as serve
    elif protocol == "dynamixel":
        from pivotd.sim.dynamixel_server import main as serve
    else:
        from pivotd.firmware_proto.mock_server import main as serve
    return int(serve(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
