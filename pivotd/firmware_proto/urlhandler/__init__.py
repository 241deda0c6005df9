"""pyserial URL handlers of the project: ``mock://`` (an in-process simulated gimbal).

Registered by appending ``"pivotd.firmware_proto.urlhandler"`` to ``serial.protocol_handler_packages``
(done by :func:`register`, called when ``pivotd.gimbal.link`` is imported).
"""

import serial

PACKAGE = __name__


def register() -> None:
    """Make ``serial.serial_for_url("mock://...")`` find this package (idempotent)."""
    if PACKAGE not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(PACKAGE)
