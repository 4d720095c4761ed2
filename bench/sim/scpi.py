"""Minimal SCPI parsing for simulators: header matching with short/long forms, channel lists.

A header pattern is written in SCPI's mixed case, e.g. ``SENSe:TEMPerature:TRANsducer:TCouple:CHECk``;
optional nodes in brackets ``[SENSe:]``. A received header matches when every node equals the
short form (the upper-case letters) or the long form, case-insensitively (IEEE 488.2 / SCPI-99).
"""

from __future__ import annotations

import re


def _node_forms(node: str) -> tuple[str, str]:
    short = "".join(c for c in node if c.isupper() or c.isdigit() or c in "*?")
    return short.upper(), node.upper()


def header_matches(pattern: str, header: str) -> bool:
    """Does ``header`` (as received) match ``pattern`` (mixed-case SCPI, ``[optional:]`` nodes)?"""
    optional = re.findall(r"\[([^\]]+):\]", pattern)
    required = re.sub(r"\[[^\]]+:\]", "", pattern)
    got = header.upper().lstrip(":").split(":")
    want = required.split(":")
    for opt in optional:  # an optional leading node may be present or absent
        if got and got[0] in _node_forms(opt):
            got = got[1:]
    if len(got) != len(want):
        return False
    return all(g in _node_forms(w) for g, w in zip(got, want))


def parse_channel_list(text: str) -> list[int]:
    """``(@101:103,105)`` -> [101, 102, 103, 105]; ValueError if malformed."""
    m = re.fullmatch(r"\s*\(@([\d:,\s]+)\)\s*", text)
    if not m:
        raise ValueError(f"not a channel list: {text!r}")
    out: list[int] = []
    for part in m.group(1).split(","):
        a, _, b = part.strip().partition(":")
        lo, hi = int(a), int(b or a)
        if hi < lo or hi - lo > 100:
            raise ValueError(f"bad channel range {part!r}")
        out.extend(range(lo, hi + 1))
    return out
