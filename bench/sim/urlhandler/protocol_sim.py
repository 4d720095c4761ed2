"""pyserial URL handler ``sim://NAME``: a serial port whose other end is a device simulator.

Modelled on pyserial's ``protocol_loop``. Reads honour the port timeout on the simulator's clock:
with a virtual clock a read that has to wait advances virtual time to the next byte the device
will send (or to the timeout), so a dry-run never sleeps; with a wall clock it really waits.
"""

from __future__ import annotations

import time
import urllib.parse as urlparse

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from bench.sim import registry

POLL_WALL_S = 0.001  # wall-clock polling step while waiting on a real-time simulator


class Serial(SerialBase):
    """Serial port connected to a registered simulated device."""

    def __init__(self, *args, **kwargs):
        self.device = None
        super().__init__(*args, **kwargs)

    def open(self) -> None:
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        name = self.from_url(self._port)
        try:
            self.device = registry.lookup(name)
        except KeyError as exc:
            raise SerialException(str(exc.args[0])) from None
        self._reconfigure_port()
        self.is_open = True
        self.reset_input_buffer()
        on_open = getattr(self.device, "on_open", None)
        if on_open is not None:
            on_open()  # a device that resets when its port opens (an Arduino's DTR)

    def from_url(self, url: str) -> str:
        parts = urlparse.urlsplit(url)
        if parts.scheme != "sim" or not parts.netloc:
            raise SerialException(f'expected "sim://NAME", got {url!r}')
        if parts.query:
            raise SerialException(f"sim:// takes no options, got {parts.query!r}")
        return parts.netloc

    def _reconfigure_port(self) -> None:
        if self.device is not None:
            self.device.set_baudrate(int(self._baudrate))

    def close(self) -> None:
        self.is_open = False
        self.device = None

    def _now(self) -> float:
        return self.device.clock.now()

    @property
    def in_waiting(self) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        return self.device.pending_bytes(self._now())

    def read(self, size: int = 1) -> bytes:
        if not self.is_open:
            raise PortNotOpenError()
        clock = self.device.clock
        out = bytearray()
        deadline = None if self._timeout is None else self._now() + self._timeout
        while len(out) < size:
            out += self.device.take_output(self._now(), size - len(out))
            if len(out) >= size or self._timeout == 0:
                break
            nxt = self.device.next_output_time()
            if getattr(clock, "virtual", False):
                if nxt is None or deadline is None or nxt > deadline:
                    if deadline is not None:
                        clock.sleep_until(deadline)
                    break
                clock.sleep_until(max(nxt, self._now()))
            else:
                if deadline is not None and self._now() >= deadline:
                    break
                if nxt is None and deadline is None:
                    break  # nothing will ever come: never block forever
                time.sleep(POLL_WALL_S)
        return bytes(out)

    def write(self, data: bytes) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        data = bytes(data)
        self.device.receive(data)
        return len(data)

    def reset_input_buffer(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()
        self.device.take_output(self._now())

    def reset_output_buffer(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()
        self.device.discard_input()

    @property
    def out_waiting(self) -> int:
        return 0

    def cancel_read(self) -> None:
        pass

    def cancel_write(self) -> None:
        pass

    def _update_break_state(self) -> None:
        pass

    def _update_rts_state(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass

    @property
    def cts(self) -> bool:
        return True

    @property
    def dsr(self) -> bool:
        return True

    @property
    def ri(self) -> bool:
        return False

    @property
    def cd(self) -> bool:
        return True


__all__ = ["Serial"]
