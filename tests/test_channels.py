"""Channel subsets as the YAML writes them (TR §4.6.1): parsed, formatted, as masks."""

from __future__ import annotations

import pytest

from pbo_runtime.config.channels import ChannelError, channels_of, format_channels, mask_of, parse_channels


@pytest.mark.parametrize(("written", "channels"), [
    ("0-5", (0, 1, 2, 3, 4, 5)),
    (6, (6,)),
    ("7", (7,)),
    ([6, 7], (6, 7)),
    (["0-3", 6, "7"], (0, 1, 2, 3, 6, 7)),
    ([" 2 - 4 "], (2, 3, 4)),
    ([7, 0], (0, 7)),
    ("63", (63,)),
])
def test_a_channel_list_reads_as_a_wiring_sheet_writes_it(written, channels):
    assert parse_channels(written) == channels


@pytest.mark.parametrize(("written", "message"), [
    ("5-0", r"^channel range '5-0' is reversed: write it low-high, e.g. '0-5'$"),
    ([0, "0-2"], r"^channel\(s\) 0 listed twice$"),
    (-1, r"^channels are numbered from 0, got: -1$"),
    (64, r"^channel 64 is beyond the 64 channels a device may have \(0-63\)$"),
    ("a-b", r"^a channel must be an integer or a range 'a-b', got: 'a-b'; e\.g\. channels: 0-5"),
    (1.5, r"^a channel must be an integer or a range 'a-b', got: 1\.5"),
    (True, r"^a channel must be an integer or a range 'a-b', got: True"),
    ([], r"^the channel list is empty"),
])
def test_a_bad_channel_list_says_what_is_wrong(written, message):
    with pytest.raises(ChannelError, match=message):
        parse_channels(written)


def test_channels_format_as_ranges_and_round_trip_through_a_mask():
    channels = (0, 1, 2, 3, 4, 5, 7, 9, 10, 63)
    assert format_channels(channels) == "0-5, 7, 9-10, 63"
    assert channels_of(mask_of(channels)) == channels
    assert mask_of(()) == 0
