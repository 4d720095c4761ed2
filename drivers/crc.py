"""CRC-16/XMODEM: one message (:func:`crc16_xmodem`) or many equal-length rows at once (numpy).

CRC-16/XMODEM: polynomial 0x1021, initial value 0, no input/output reflection, no final XOR
(check value 0x31C3 for the ASCII bytes ``123456789``). It is what :func:`binascii.crc_hqx`
computes with a start value of 0. Because the CRC has no final XOR, running it over a message
followed by its own CRC (big-endian) gives 0, which the batch decoder uses as its validity test.

The batch version works on two message bytes per step: for a 16-bit, non-reflected CRC with the
register ``r`` and the next big-endian 16-bit message word ``w``, the register after the two bytes
is ``T2[r ^ w]``, where ``T2[v]`` is the CRC of the two bytes of ``v`` from a zero register. The
65536-entry table (128 KiB, uint16) and the 256-entry byte table are built once at import with numpy.
"""

from __future__ import annotations

import binascii

import numpy as np

POLY = 0x1021
"""CRC-16/XMODEM generator polynomial (x^16 + x^12 + x^5 + 1, top bit implicit)."""

CHECK_VALUE = 0x31C3
"""CRC-16/XMODEM of b"123456789" (the catalogue check value)."""


def _shift_table(values: np.ndarray, nbits: int) -> np.ndarray:
    """Shift 16-bit registers ``values`` through ``nbits`` zero message bits (vectorised)."""
    reg = values.astype(np.uint32)
    for _ in range(nbits):
        top = (reg & 0x8000) != 0
        reg = (reg << 1) & 0xFFFF
        reg[top] ^= POLY
    return reg.astype(np.uint16)


# T1[b]: register after one byte b from a zero register (the register starts as b << 8).
_T1: np.ndarray = _shift_table(np.arange(256, dtype=np.uint32) << 8, 8)
# T2[v]: register after the two bytes (v >> 8, v & 0xFF) from a zero register (it starts as v).
_T2: np.ndarray = _shift_table(np.arange(65536, dtype=np.uint32), 16)
_T1.setflags(write=False)
_T2.setflags(write=False)


def crc16_xmodem(data: bytes, init: int = 0) -> int:
    """CRC-16/XMODEM of ``data`` (any bytes-like object); an int in 0..65535.

    ``init`` is the starting register (0 for a whole message; a previous CRC to continue one).
    """
    return binascii.crc_hqx(data, init)


def crc16_words(words: np.ndarray, init: int = 0) -> np.ndarray:
    """CRC-16/XMODEM of rows given as 16-bit big-endian message words.

    ``words`` is an (n, k) array of 16-bit words (any integer dtype, including a ``>u2`` view of
    a uint8 matrix), each row being a message of 2·k bytes in transmission order. Returns the
    (n,) uint16 CRCs. ``init`` is the starting register (0 = CRC-16/XMODEM of the rows alone).
    The loop runs over the k columns, never over the rows.
    """
    words = np.asarray(words)
    if words.ndim != 2:
        raise ValueError(f"crc16_words expects an (n, k) array, got shape {words.shape}")
    n, k = words.shape
    if k == 0:
        return np.full(n, init & 0xFFFF, dtype=np.uint16)
    cols = np.ascontiguousarray(words.T, dtype=np.uint16)  # each column contiguous, native order
    first = cols[0] ^ np.uint16(init & 0xFFFF) if init & 0xFFFF else cols[0]  # never modify the caller's array
    crc = _T2.take(first)
    idx = np.empty(n, dtype=np.uint16)
    for j in range(1, k):
        np.bitwise_xor(crc, cols[j], out=idx)
        _T2.take(idx, out=crc)
    return crc


def crc16_xmodem_rows(rows: np.ndarray, init: int = 0) -> np.ndarray:
    """CRC-16/XMODEM of every row of an (n, m) uint8 array; returns an (n,) uint16 array.

    Equivalent to ``[binascii.crc_hqx(r.tobytes(), init) for r in rows]`` but vectorised: two
    bytes per step through a 65536-entry table, plus one byte-table step when m is odd. ``init``
    is the starting register (0 for whole messages; the CRC of a common prefix to continue it).
    """
    rows = np.asarray(rows)
    if rows.ndim != 2:
        raise ValueError(f"crc16_xmodem_rows expects an (n, m) array, got shape {rows.shape}")
    if rows.dtype != np.uint8:
        if rows.size and (rows.min() < 0 or rows.max() > 255):
            raise ValueError("crc16_xmodem_rows: values outside 0..255")
        rows = rows.astype(np.uint8)
    n, m = rows.shape
    even = m - (m % 2)
    if even:
        if m == even and rows.strides[1] == 1:  # bytes of a row adjacent: read words in place
            words = rows.view(">u2")
        else:
            words = (rows[:, 0:even:2].astype(np.uint16) << 8) | rows[:, 1:even:2]
        crc = crc16_words(words, init)
    else:
        crc = np.full(n, init & 0xFFFF, dtype=np.uint16)
    if m % 2:
        last = rows[:, m - 1]
        crc = (crc << np.uint16(8)) ^ _T1[(crc >> np.uint16(8)) ^ last]
    return crc
