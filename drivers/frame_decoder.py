"""Decoding a board's byte stream with its frame description: batches of data frames as numpy
columns, the other frames as replies, and the link's error counts.

:class:`FrameDecoder` follows the sequential rule of docs/acs-board-protocol.md ("Receiving") for
any :class:`drivers.board_frames.FrameDescription`, in numpy batches (all sync candidates and all
data-frame checks of a feed at once; a Python loop only over the rare other frames).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drivers.board_frames import TYPES, FrameDescription
from drivers.crc import crc16_xmodem_rows


@dataclass
class DecodedBatch:
    """What one :meth:`FrameDecoder.feed` produced. Arrays have one row per good data frame:
    ``counter`` (frames, uint), ``board_time_s`` (s, unwrapped), ``status`` (uint) and
    :attr:`columns`, the physical values of the board's signal fields by name (float64, (n,) or
    (n, count); units: :attr:`Field.units`)."""

    counter: np.ndarray
    board_time_s: np.ndarray
    status: np.ndarray
    columns: dict[str, np.ndarray]
    replies: list[tuple[int, bytes]] = field(default_factory=list)
    crc_errors: int = 0
    garbage_bytes: int = 0
    dropped_frames: int = 0
    frames_ok: int = 0
    layout_errors: int = 0
    """Frames with a good check whose constant fields differ from the description (another output
    configuration than described): not decoded, their bytes counted as garbage."""

    @classmethod
    def empty(cls, d: FrameDescription) -> "DecodedBatch":
        def kind(name: str) -> str:
            f = d.field(name)
            return TYPES[f.type][0] if f is not None else "u2"

        return cls(np.zeros(0, kind("counter")), np.zeros(0), np.zeros(0, kind("status")),
                   {f.name: np.zeros((0,) + f.shape) for f in d.signals})

    # the names bench's own code reads (docs/acs-board-protocol.md): the columns of the standard fields
    gyro_dps = property(lambda self: self.columns["gyro"], doc="``gyro`` (n, 3), deg/s")
    accel_g = property(lambda self: self.columns["accel"], doc="``accel`` (n, 3), g")
    mag_ut = property(lambda self: self.columns["mag"], doc="``mag`` (n, 3), µT")
    temp_degc = property(lambda self: self.columns["temp"], doc="``temp`` (n,) or (n, k), °C")


COUNTS = ("crc_errors", "garbage_bytes", "dropped_frames", "frames_ok", "layout_errors")
"""The counts of a :class:`DecodedBatch`, kept cumulatively by the :class:`FrameDecoder`."""


def merge_batches(batches: list[DecodedBatch]) -> DecodedBatch:
    """Concatenate decoded batches in order: arrays joined, reply lists joined, counts summed."""
    if len(batches) == 1:
        return batches[0]
    first = batches[0]
    return DecodedBatch(
        np.concatenate([b.counter for b in batches]), np.concatenate([b.board_time_s for b in batches]),
        np.concatenate([b.status for b in batches]),
        {k: np.concatenate([b.columns[k] for b in batches], axis=0) for k in first.columns},
        [r for b in batches for r in b.replies], **{k: sum(getattr(b, k) for b in batches) for k in COUNTS})


class FrameDecoder:
    """Streaming batch decoder of the frames of ``description``. Feed it bytes in any chunking.

    Resynchronises after garbage; counts check errors (frames with a plausible header whose check
    fails), garbage bytes (bytes skipped that were not part of a good frame, including those of
    corrupted frames), dropped frames (gaps in the data-frame counter, modulo its width, also
    across feeds) and unwraps the board's clock. Cumulative totals are attributes. The sequential
    rule it follows, in numpy batches, is docs/acs-board-protocol.md "Receiving"."""

    def __init__(self, description: FrameDescription, accept_unknown_types: bool = False) -> None:
        """``accept_unknown_types``: treat frames of any type as candidates (the board side uses this
        so that it can NAK unknown commands; the host side skips them as garbage)."""
        d = self.d = description
        self._plausible = np.ones(256, dtype=bool)
        if not accept_unknown_types:
            self._plausible[:] = False
            self._plausible[list(d.known_types)] = True
        self._sync = np.frombuffer(d.sync, np.uint8)
        self._dtype = d.data_dtype
        self._consts = [(f.name, f.value) for f in d.fields if f.value is not None]
        self._counter = d.field("counter")
        self._clock = d.field("board_time")
        self._status = d.field("status")
        self._prefix_crc = d.check.one(d.header_bytes(d.data_id, d.data_payload_len)[d.check_from:])
        self._tail = b""
        self._last_counter: int | None = None
        self._last_ticks: int | None = None
        self._wraps = 0
        for k in COUNTS:
            setattr(self, k, 0)

    @property
    def pending_bytes(self) -> int:
        """Bytes held back until more data shows whether they start a frame."""
        return len(self._tail)

    def _lengths(self, buf: np.ndarray, cand: np.ndarray) -> np.ndarray:
        d = self.d
        at = cand + d.length_at
        if d.length_size == 1:
            return buf[at].astype(np.int64)
        lo, hi = (buf[at], buf[at + 1]) if d.byte_order == "<" else (buf[at + 1], buf[at])
        return lo.astype(np.int64) | (hi.astype(np.int64) << 8)

    def feed(self, data: bytes) -> DecodedBatch:
        """Decode ``data`` (appended to the bytes held back from the previous feed)."""
        d = self.d
        buf_bytes = self._tail + bytes(data)
        buf = np.frombuffer(buf_bytes, dtype=np.uint8)
        size = buf.size
        k = self._sync.size
        hl = d.header_len
        if size >= k:
            hit = buf[: size - k + 1] == self._sync[0]
            for j in range(1, k):
                hit &= buf[j: size - k + 1 + j] == self._sync[j]
            cand = np.flatnonzero(hit)
        else:
            cand = np.zeros(0, np.int64)
        # Stop points: places from which the rest of the buffer is undecidable (an incomplete
        # header or frame, or trailing bytes that may be part of a sync word) unless they turn out
        # to lie inside an accepted frame.
        stops = [j for j in range(max(0, size - k + 1), size) if buf_bytes[j:] == d.sync[: size - j]]
        header_ok = cand + hl <= size
        if not header_ok.all():
            stops.append(int(cand[~header_ok][0]))
        cand = cand[header_ok]
        ftype = buf[cand + d.type_at]
        flen = self._lengths(buf, cand)
        plausible = self._plausible[ftype] & np.where(ftype == d.data_id, flen == d.data_payload_len, flen <= d.max_payload)
        if d.version is not None:
            plausible &= buf[cand + d.version_at] == d.version
        cand, ftype, flen = cand[plausible], ftype[plausible], flen[plausible]
        ends = cand + d.overhead + flen
        complete = ends <= size
        if not complete.all():
            stops.extend(cand[~complete].tolist())
            cand, ftype, ends = cand[complete], ftype[complete], ends[complete]

        good = np.zeros(cand.size, dtype=bool)
        is_data = ftype == d.data_id
        d_idx = np.flatnonzero(is_data)
        rows = np.zeros((0, d.data_frame_len), dtype=np.uint8)
        frames = None
        layout_bad = 0
        if d_idx.size:
            # gather whole frames as rows (one copy each), check them in one pass
            rows = np.lib.stride_tricks.sliding_window_view(buf, d.data_frame_len)[cand[d_idx]]
            frames = rows.view(self._dtype).reshape(rows.shape[0])
            ok = self._check_rows(rows, frames)
            if self._consts:
                fits = np.ones(ok.shape, dtype=bool)
                for name, value in self._consts:
                    fits &= frames[name] == value
                layout_bad_mask = ok & ~fits
                ok &= fits
            good[d_idx] = ok
        cs, co = d.check.size, d.check_from
        for i in np.flatnonzero(~is_data):  # replies and commands are rare: a loop is fine
            s, e = int(cand[i]), int(ends[i])
            if cs:
                good[i] = d.check.one(buf_bytes[s + co: e - cs]) == int.from_bytes(
                    buf_bytes[e - cs: e], "big" if d.check_byte_order == ">" else "little")
            else:
                good[i] = True

        g_start, g_end, g_type = cand[good], ends[good], ftype[good]
        data_good = good[d_idx]
        if g_start.size > 1 and np.any(g_end[:-1] > g_start[1:]):  # rare: overlapping valid frames
            accept = _non_overlapping(g_start, g_end)
            data_good = data_good.copy()
            data_good[data_good] = accept[g_type == d.data_id]
            g_start, g_end, g_type = g_start[accept], g_end[accept], g_type[accept]
        # the first stop point outside every accepted frame ends what this feed can decide
        limit = size
        if stops:
            st = np.unique(np.asarray(stops, dtype=np.int64))
            if g_start.size:
                st = st[~_inside(st, g_start, g_end)]
            if st.size:
                limit = int(st[0])
        if g_start.size and g_start[-1] >= limit:  # frames after the stop point wait for the next feed
            keep = g_start < limit
            data_good = data_good.copy()
            data_good[data_good] = keep[g_type == d.data_id]
            g_start, g_end, g_type = g_start[keep], g_end[keep], g_type[keep]
        bad = cand[~good]
        if d_idx.size and self._consts:
            layout_starts = cand[d_idx][layout_bad_mask]
            layout_starts = layout_starts[layout_starts < limit]
            if g_start.size:
                layout_starts = layout_starts[~_inside(layout_starts, g_start, g_end)]
            layout_bad = int(layout_starts.size)
            bad = np.setdiff1d(bad, layout_starts, assume_unique=True)
        bad = bad[bad < limit]
        if bad.size and g_start.size:
            bad = bad[~_inside(bad, g_start, g_end)]
        crc_errors = int(bad.size)
        garbage = limit - int((g_end - g_start).sum())
        self._tail = buf_bytes[limit:]

        if frames is not None and not data_good.all():
            frames = rows[data_good].view(self._dtype).reshape(-1)  # rows of bytes copy faster than structured records
        batch = self._decode_data(frames)
        other = g_type != d.data_id
        if other.any():
            for s, e, t in zip(g_start[other].tolist(), g_end[other].tolist(), g_type[other].tolist()):
                batch.replies.append((t, buf_bytes[s + hl: e - cs]))
        batch.crc_errors = crc_errors
        batch.garbage_bytes = garbage
        batch.frames_ok = int(g_start.size)
        batch.layout_errors = layout_bad
        for k in COUNTS:
            setattr(self, k, getattr(self, k) + getattr(batch, k))
        return batch

    def _check_rows(self, rows: np.ndarray, frames: np.ndarray) -> np.ndarray:
        d = self.d
        if not d.check.size:
            return np.ones(rows.shape[0], dtype=bool)
        covered = rows[:, d.check_from:d.check_at]
        if d.check.name in ("crc16_xmodem", "crc16_ccitt_false") and d.check_byte_order == ">" and d.data_payload_len % 2 == 0:
            # no final XOR: the CRC over the covered bytes and the big-endian CRC is 0; the data
            # header's constant bytes go in as the starting register (the rows' words are then read in place)
            return crc16_xmodem_rows(rows[:, d.header_len:], self._prefix_crc) == 0
        return d.check.rows(covered) == frames["check"]

    def _decode_data(self, frames: np.ndarray | None) -> DecodedBatch:
        """Decode good data frames (a structured array of the description's data dtype)."""
        d = self.d
        if frames is None or frames.shape[0] == 0:
            return DecodedBatch.empty(d)
        n = frames.shape[0]
        dropped = 0
        if self._counter is not None:
            mod = self._counter.modulus
            counter = frames["counter"].astype(TYPES[self._counter.type][0])
            c = counter.astype(np.int64)
            if self._last_counter is not None:
                step = (c - np.concatenate(([self._last_counter], c[:-1]))) % mod
            else:
                step = np.concatenate(([1], (c[1:] - c[:-1]) % mod))
            dropped = int(np.where(step == 0, 0, step - 1).sum())
            self._last_counter = int(c[-1])
        else:
            counter = np.zeros(n, np.uint16)
        ticks = frames["board_time"].astype(np.int64)
        prev = np.concatenate(([self._last_ticks if self._last_ticks is not None else ticks[0]], ticks[:-1]))
        wraps = self._wraps + np.cumsum(ticks < prev)
        self._wraps = int(wraps[-1])
        self._last_ticks = int(ticks[-1])
        clock = self._clock
        board_time_s = (ticks + wraps * clock.modulus) * clock.scale
        if clock.offset:
            board_time_s += clock.offset
        status = frames["status"].astype(TYPES[self._status.type][0]) if self._status is not None else np.zeros(n, np.uint16)
        return DecodedBatch(counter, board_time_s, status, d.decode_fields(frames), dropped_frames=dropped)


def _inside(points: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Which ``points`` fall strictly after the start and before the end of a (sorted, disjoint) frame."""
    j = np.searchsorted(starts, points, side="right") - 1
    return (j >= 0) & (points > starts[np.maximum(j, 0)]) & (points < ends[np.maximum(j, 0)])


def _non_overlapping(starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Greedy left-to-right choice of check-valid frames that do not overlap (rare path)."""
    accept = np.zeros(starts.size, dtype=bool)
    end = -1
    for i, (s, e) in enumerate(zip(starts.tolist(), ends.tolist())):
        if s >= end:
            accept[i] = True
            end = e
    return accept


