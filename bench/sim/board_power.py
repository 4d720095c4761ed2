"""What the simulated sensor board draws from a supply that powers it (bench/sim/power.py).

The board is ESTCube-2's AOCS prototype: an STM32F4 MCU at 84 MHz with its sensors, powered
through its mini-USB connector (ESTCube-2 thesis, seed 004, sections 2.2 and 2.5). Its draw at a
supply voltage within its range, in A:

* **inrush**: at power-on the board's input capacitance charges; USB 2.0 allows a device at most
  10 µF on VBUS (USB 2.0 specification section 7.2.4.1), taken as the board's. Charged to ``V``
  within the supply's output rise time ``RISE_S`` it draws ``C·V/RISE_S`` for that time (50 mA at
  5 V) on top of the rest;
* **MCU**: the STM32F4 running from power-on, ``MCU_A`` [U];
* **sensors** while powered (the board's SENSOR_POWER): the MPU-6000 3.6 mA and the LIS3MDL 270 µA
  (ESTCube-2 Tables 2.1 and 2.3, from their datasheets);
* **streaming** at output data rate ``ODR``: the UART sends one data frame per sample, ``10·L/baud``
  seconds of line activity per frame (8N1, ``L`` bytes; docs/acs-board-protocol.md "Link budget"),
  at ``UART_TX_A`` while transmitting [U]: ``ODR·10·L/baud·UART_TX_A`` (4.9 mA at 100 Hz with our
  38-byte frames at 115200 baud).

Its supply range is VBUS at a USB device: 4.40 V (a low-power port) to 5.25 V (USB 2.0
specification, section 7.3.2, Table 7-7). Outside it the board is off; after power comes within it
the MCU boots in ``BOOT_S`` [U] and the board is in its power-up state (docs/acs-board-protocol.md:
sensors off, not streaming).

[U] marks our choices where no source is at hand: the MCU's run current (the STM32F401's datasheet
gives its Run-mode current per MHz, not among our sources; 128 µA/MHz at 84 MHz is 10.8 mA), the
UART bridge's transmit current, the supply's rise time and the boot time.
"""

from __future__ import annotations

SUPPLY_RANGE_V = (4.40, 5.25)
"""VBUS at a USB device: low-power port minimum to maximum (USB 2.0 section 7.3.2, Table 7-7)."""
INPUT_CAPACITANCE_F = 10e-6
"""The most a USB device may present on VBUS (USB 2.0 section 7.2.4.1)."""
RISE_S = 1e-3
"""[U] The supply output's rise time at switch-on (s)."""
BOOT_S = 0.05
"""[U] From power within range to the MCU answering (s)."""
MCU_A = 10.8e-3
"""[U] STM32F4 in Run mode at 84 MHz: 128 µA/MHz (STM32F401 datasheet, not among our sources) (A)."""
SENSORS_A = 3.6e-3 + 0.27e-3
"""MPU-6000 (3.6 mA) and LIS3MDL (270 µA) while powered (ESTCube-2 Tables 2.1, 2.3) (A)."""
UART_TX_A = 15e-3
"""[U] Extra draw while the UART bridge transmits (A)."""


def board_current_a(t: float, volts: float, on_since: float, *, sensors_on: bool, streaming: bool, odr_hz: float,
                    frame_bytes: int, baudrate: int) -> float:
    """The board's draw (A) at run time ``t`` (s), fed ``volts`` since ``on_since`` (s) (see the
    module docstring)."""
    i = MCU_A
    if t - on_since < RISE_S:
        i += INPUT_CAPACITANCE_F * volts / RISE_S
    if sensors_on:
        i += SENSORS_A
    if streaming:
        i += odr_hz * 10.0 * frame_bytes / baudrate * UART_TX_A
    return i
