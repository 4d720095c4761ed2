"""Typed errors every driver raises. Drivers know nothing of ``bench``; ``bench.errors`` re-exports
these so the application catches them by the same names.

* :class:`InstrumentTimeout`: no answer within the driver's timeout (s);
* :class:`ProtocolError`: an answer the protocol does not allow (bad frame, NAK, wrong length);
* :class:`DeviceFault`: the instrument reports a fault of its own (failed built-in test, alarm);
* :class:`NotConfigured`: the instrument answers as what it is but is not set up as the lab's
  config expects (``fix`` says what to send it);
* :class:`InstrumentError`: their base, also raised for a lost or unopenable link.
"""

from __future__ import annotations


class InstrumentError(Exception):
    """Base class of instrument faults raised by drivers."""


class InstrumentTimeout(InstrumentError):
    """The instrument did not answer within the timeout."""


class ProtocolError(InstrumentError):
    """The instrument answered something the protocol does not allow (bad frame, NAK, wrong length)."""


class DeviceFault(InstrumentError):
    """The instrument reports a fault of its own (failed built-in test, alarm)."""


class NotConfigured(InstrumentError):
    """The instrument answers, as what it is, but is not set up as the config expects (a plain
    firmware without the lab's settings). ``fix`` is what to send it or do so that it is."""

    def __init__(self, message: str, fix: str):
        super().__init__(message)
        self.fix = fix
