"""Channel subsets of port-based I/O devices (TR §4.6.1): how the YAML names them, and their bit masks.

An I/O device (an ADC, a DAC, a parallel port) is a collection of ports, here called channels,
numbered from 0. A task opens all of them or a subset; the subset is written in the YAML as an
engineer writes it on a wiring sheet:

    channels: 0-5           one range, both ends included
    channels: 6             one channel
    channels: [0-3, 6, 7]   a list of channels and ranges

Inside the runtime a subset is a sorted tuple of channel numbers, and, where ownership is kept
in the state table, a 64-bit mask (so a device has at most `MAX_CHANNELS` channels).
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from typing import Any

MAX_CHANNELS = 64  # one int64 mask per holder in the table's device region
_RANGE = re.compile(r"^\s*(\d+)\s*-\s*(\d+)\s*$")
EXAMPLE = "e.g. channels: 0-5, channels: 6, or channels: [0-3, 6, 7]"


class ChannelError(ValueError):
    """A channel list that is not integers and 'a-b' ranges, reversed, repeated or out of range."""


def parse_channels(value: Any) -> tuple[int, ...]:
    """The sorted channels `value` names (see the module docstring), or ChannelError saying why."""
    items = value if isinstance(value, (list, tuple)) else [value]
    if not items:
        raise ChannelError(f"the channel list is empty; {EXAMPLE}")
    channels: list[int] = []
    for item in items:
        if isinstance(item, bool) or not isinstance(item, (int, str)):
            raise ChannelError(f"a channel must be an integer or a range 'a-b', got: {item!r}; {EXAMPLE}")
        if isinstance(item, int):
            first = last = item
        else:
            match = _RANGE.match(item)
            if item.strip().isdigit():
                first = last = int(item)
            elif match:
                first, last = int(match.group(1)), int(match.group(2))
            else:
                raise ChannelError(f"a channel must be an integer or a range 'a-b', got: {item!r}; {EXAMPLE}")
            if first > last:
                raise ChannelError(f"channel range {item!r} is reversed: write it low-high, e.g. '{last}-{first}'")
        if first < 0:
            raise ChannelError(f"channels are numbered from 0, got: {first}")
        if last >= MAX_CHANNELS:
            raise ChannelError(f"channel {last} is beyond the {MAX_CHANNELS} channels a device may have (0-{MAX_CHANNELS - 1})")
        channels.extend(range(first, last + 1))
    repeated = sorted({c for c in channels if channels.count(c) > 1})
    if repeated:
        raise ChannelError(f"channel(s) {format_channels(repeated)} listed twice")
    return tuple(sorted(channels))


def format_channels(channels: Iterable[int]) -> str:
    """'0-5, 7' for (0, 1, 2, 3, 4, 5, 7): ranges as a wiring sheet writes them."""
    ordered = sorted(set(channels))
    parts: list[str] = []
    i = 0
    while i < len(ordered):
        j = i
        while j + 1 < len(ordered) and ordered[j + 1] == ordered[j] + 1:
            j += 1
        parts.append(str(ordered[i]) if i == j else f"{ordered[i]}-{ordered[j]}")
        i = j + 1
    return ", ".join(parts)


def mask_of(channels: Iterable[int]) -> int:
    """The channels as a bit mask (bit c set for channel c)."""
    mask = 0
    for c in channels:
        mask |= 1 << c
    return mask


def channels_of(mask: int) -> tuple[int, ...]:
    """The channels a mask holds, ascending."""
    return tuple(c for c in range(MAX_CHANNELS) if mask >> c & 1)


def all_channels(count: int) -> tuple[int, ...]:
    return tuple(range(count))
