"""Minimal SCPI parsing for simulators: header matching with short/long forms, channel lists.

A header pattern is written in SCPI's mixed case, e.g. ``SENSe:TEMPerature:TRANsducer:TCouple:CHECk``;
optional nodes in brackets ``[SENSe:]``. A received header matches when every node equals the
short form (the upper-case letters) or the long form, case-insensitively (IEEE 488.2 / SCPI-99).
"""

from __future__ import annotations

import functools
import re


def _node_forms(node: str) -> tuple[str, str]:
    short = "".join(c for c in node if c.isupper() or c.isdigit() or c in "*?")
    return short.upper(), node.upper()


@functools.lru_cache(maxsize=512)
def _pattern_forms(pattern: str) -> tuple[tuple[tuple[str, str], ...], tuple[tuple[str, str], ...]]:
    """(forms of the optional leading nodes, forms of the required nodes) of a header pattern."""
    optional = re.findall(r"\[([^\]]+):\]", pattern)
    required = re.sub(r"\[[^\]]+:\]", "", pattern)
    return tuple(_node_forms(o) for o in optional), tuple(_node_forms(w) for w in required.split(":"))


def header_matches(pattern: str, header: str) -> bool:
    """Does ``header`` (as received) match ``pattern`` (mixed-case SCPI, ``[optional:]`` nodes)?"""
    optional, want = _pattern_forms(pattern)
    got = header.upper().lstrip(":").split(":")
    for forms in optional:  # an optional leading node may be present or absent
        if got and got[0] in forms:
            got = got[1:]
    if len(got) != len(want):
        return False
    return all(g in forms for g, forms in zip(got, want))


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
