"""Quantities in YAML: numbers in SI units or strings with a unit."""

from __future__ import annotations

import re

import pytest

from pbo_runtime.config.units import DATA_RATE, FREQUENCY, SIZE, TIME, parse_quantity


@pytest.mark.parametrize(
    ("text", "seconds"),
    [
        ("1 ms", 1e-3),
        ("500 us", 500e-6),
        ("500 µs", 500e-6),
        ("2 s", 2.0),
        ("1.5 min", 90.0),
        ("10ns", 10e-9),
        ("1e-3 s", 1e-3),
        ("-5 ms", -5e-3),
    ],
)
def test_a_time_with_a_unit_becomes_seconds(text: str, seconds: float) -> None:
    assert parse_quantity(text, TIME) == pytest.approx(seconds)


@pytest.mark.parametrize(("text", "hertz"), [("1 kHz", 1e3), ("100 Hz", 100.0), ("2.5 MHz", 2.5e6)])
def test_a_frequency_with_a_unit_becomes_hertz(text: str, hertz: float) -> None:
    assert parse_quantity(text, FREQUENCY) == pytest.approx(hertz)


@pytest.mark.parametrize(
    ("text", "rate"),
    [("40 MB/s", 40e6), ("1 GB/s", 1e9), ("100 kB/s", 100e3), ("1 MiB/s", 1024.0**2), ("8 B/s", 8.0)],
)
def test_a_data_rate_is_decimal_si_unless_binary(text: str, rate: float) -> None:
    assert parse_quantity(text, DATA_RATE) == pytest.approx(rate)


@pytest.mark.parametrize(("text", "size"), [("16 B", 16.0), ("4 KiB", 4096.0), ("2 kB", 2000.0), ("1 MiB", 1024.0**2)])
def test_a_size_becomes_bytes(text: str, size: float) -> None:
    assert parse_quantity(text, SIZE) == pytest.approx(size)


@pytest.mark.parametrize("value", [0.001, 1, "0.001", "1e-3"])
def test_a_bare_number_is_already_in_si_units(value: object) -> None:
    assert parse_quantity(value, TIME) == pytest.approx(float(value))  # type: ignore[arg-type]


def test_an_unknown_unit_says_what_was_expected_and_found() -> None:
    with pytest.raises(ValueError, match=re.escape("expected a time like '1 ms' or a number of seconds, got: '5 kg'")) as info:
        parse_quantity("5 kg", TIME)
    assert "ms" in str(info.value).split("units:")[1]


def test_a_unit_of_another_kind_is_named() -> None:
    with pytest.raises(ValueError, match=r"^expected a time .*, got: '1 kHz' \(that is a frequency\)$"):
        parse_quantity("1 kHz", TIME)


@pytest.mark.parametrize("value", [True, None, [1], {"a": 1}, "fast", "", "ms", "1 2 ms"])
def test_a_value_that_is_no_quantity_is_refused(value: object) -> None:
    with pytest.raises(ValueError, match=r"^expected a size like '16 B' or a number of bytes, got: "):
        parse_quantity(value, SIZE)


@pytest.mark.parametrize("value", [float("inf"), float("nan"), "inf s"])
def test_a_quantity_must_be_finite(value: object) -> None:
    with pytest.raises(ValueError, match=r"^expected a time"):
        parse_quantity(value, TIME)


def test_an_unknown_kind_of_quantity_is_a_programming_error() -> None:
    with pytest.raises(ValueError, match=r"^unknown quantity kind 'mass'"):
        parse_quantity(1, "mass")
