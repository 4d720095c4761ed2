"""CRC-16/XMODEM (poly 0x1021, init 0, no reflection, no final xor): one frame or many rows at once.

Check value: ``crc16_xmodem(b"123456789") == 0x31C3``. The scalar form is ``binascii.crc_hqx``
(C); the batch form processes two bytes per step with a 65536-entry table, looping over the
columns of an (n, m) byte matrix, never over its rows.
"""

from __future__ import annotations

import binascii

import numpy as np


def crc16_xmodem(data: bytes) -> int:
    """CRC-16/XMODEM of ``data``."""
    return binascii.crc_hqx(data, 0)


def _byte_table() -> np.ndarray:
    crc = np.arange(256, dtype=np.uint32) << 8
    for _ in range(8):
        crc = np.where(crc & 0x8000, (crc << 1) ^ 0x1021, crc << 1) & 0xFFFF
    return crc.astype(np.uint16)


_T8 = _byte_table()
_x = np.arange(65536, dtype=np.uint32)
_c1 = _T8[_x >> 8].astype(np.uint32)
_T16 = (((_c1 << 8) & 0xFFFF) ^ _T8[((_c1 >> 8) ^ (_x & 0xFF)) & 0xFF]).astype(np.uint16)
"""_T16[w] = register after shifting the 16 bits of w into a zero register; crc' = _T16[crc ^ w]."""
del _x, _c1


def crc16_xmodem_rows(rows: np.ndarray) -> np.ndarray:
    """CRC-16/XMODEM of every row of an (n, m) uint8 array; returns (n,) uint16."""
    rows = np.asarray(rows, dtype=np.uint8)
    if rows.ndim != 2:
        raise ValueError(f"expected an (n, m) byte matrix, got shape {rows.shape}")
    n, m = rows.shape
    crc = np.zeros(n, dtype=np.uint16)
    start = 0
    if m % 2:
        crc = _T8[rows[:, 0]]  # first byte from a zero register
        start = 1
    if m - start:
        words = (rows[:, start:].astype(np.uint16) << 8)
        words = words[:, 0::2] | rows[:, start + 1::2]
        for j in range(words.shape[1]):
            crc = _T16[crc ^ words[:, j]]
    return crc
