"""`pbo check` on devices (TR §4.6): channel subsets, sensors wired through I/O devices, driver options.

The checker asks the registered drivers what they are (how many channels, which kind of I/O device
a sensor reads through, which options they take), so these run against the library's drivers.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from pbo_runtime.config.loader import CheckResult, check_file
from pbo_runtime.errors import ConfigError

BASE = """\
subsystem: devices
rtpus: [rtpu0, rtpu1]
devices:
  adc0: {driver: adc}
  dac0: {driver: dac}
  pio0: {driver: parallel_port}
  ft_a: {driver: ft_parallel, io: {device: pio0, channels: 0-7}}
  ft_b: {driver: ft_analog, io: {device: adc0, channels: 0-5}, calibration: [[1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0], \
[0, 0, 1, 0, 0, 0], [0, 0, 0, 1, 0, 0], [0, 0, 0, 0, 1, 0], [0, 0, 0, 0, 0, 1]], offset: [0, 0, 0, 0, 0, 0]}
variables:
  v2:  {type: float64, shape: [2]}
  v2b: {type: float64, shape: [2]}
  f_m: {type: float64, shape: [6]}
  out: {type: float64, shape: [2], initial: 0}
tasks:
  force: {module: ft_sensor, rtpu: rtpu1, period: 1 ms, params: {device: ft_b}, resources: [ft_b]}
  aux:   {module: analog_input, rtpu: rtpu0, period: 1 ms, params: {device: adc0}, ports: {v: v2},
          resources: [{device: adc0, channels: 6-7}]}
  drive: {module: analog_output, rtpu: rtpu0, period: 1 ms, params: {device: dac0}, ports: {v: out},
          resources: [{device: dac0, channels: [0, 1]}]}
configurations:
  run: [force, aux, drive]
plant: {model: puma560, timestep: 1 ms}
"""


def check(tmp_path: Path, text: str) -> CheckResult:
    path = tmp_path / "devices.yaml"
    path.write_text(text)
    return check_file(path)


def changed(old: str, new: str, text: str = BASE) -> str:
    assert text.count(old) == 1, old
    return text.replace(old, new)


def at(text: str, fragment: str) -> tuple[int, int]:
    """1-based line and column of `fragment` in `text`."""
    index = text.index(fragment)
    line = text.count("\n", 0, index) + 1
    return line, index - (text.rfind("\n", 0, index) + 1) + 1


def expect(tmp_path: Path, text: str, code: str, fragment: str, message: str, warning: bool = False) -> ConfigError:
    result = check(tmp_path, text)
    found = [d for d in (result.warnings if warning else result.errors) if d.code == code]
    line, column = at(text, fragment)
    assert found, [d.format() for d in [*result.errors, *result.warnings]]
    kind = "warning" if warning else "error"
    where = f"{tmp_path}/devices.yaml:{line}:{column}: {kind}[{code}]: "
    assert found[0].format().startswith(where), found[0].format()
    assert re.match(message, found[0].message), found[0].message
    return found[0]


def test_the_base_file_is_clean_and_keeps_each_task_s_channels(tmp_path):
    result = check(tmp_path, BASE)
    assert result.errors == [], [d.format() for d in result.errors]
    assert {w.code for w in result.warnings} == {"W202"}  # the inputs' variables feed nothing here
    sub = result.subsystem
    assert sub.tasks["aux"].resources == ("adc0",) and sub.tasks["aux"].resource_channels == {"adc0": (6, 7)}
    assert sub.tasks["force"].resources == ("ft_b",) and sub.tasks["force"].resource_channels == {}
    io = sub.devices["ft_b"].io
    assert (io.device, io.channels) == ("adc0", (0, 1, 2, 3, 4, 5))
    assert "io" not in sub.devices["ft_b"].options and "calibration" in sub.devices["ft_b"].options


def edited(*edits: tuple[str, str]) -> str:
    """BASE with each (old, new) edit made in turn."""
    text = BASE
    for old, new in edits:
        text = changed(old, new, text)
    return text


def mistake(name: str, text: str, code: str, fragment: str, message: str, hint: str | None = None):
    """A file with one mistake: its first `code` error is at `fragment`, its message matches `message`
    (anchored), and its hint, if given, is searched for `hint` (both regexes)."""
    return pytest.param(text, code, fragment, message, hint, id=name)


def malformed_channels(name: str, written: str, message: str):
    return mistake(name, changed("channels: 6-7}]", f"channels: {written}}}]"), "E604", f"{written}}}]", message)


def wrong_io(name: str, old: str, new: str, fragment: str, message: str):
    return mistake(name, changed(old, new), "E606", fragment, message)


ONE_MISTAKE = [
    # channels claimed twice
    mistake("channels_a_task_claims_that_a_sensor_s_io_holds_in_the_same_configuration_are_an_error",
            changed("channels: 6-7}]", "channels: 4-7}]"), "E603", "{device: adc0, channels: 4-7",
            r"device 'adc0': 'aux' \(line 17\) claims channels 4-7, but 'force' \(line 15, through device 'ft_b'\) "
            r"holds 0-5 in configuration 'run'; they overlap on 4-5$",
            hint=r"^a channel has one user per configuration"),
    mistake("two_tasks_claiming_overlapping_channels_get_a_hint_with_the_free_ones",
            edited(("  drive:", "  spare: {module: analog_input, rtpu: rtpu1, period: 1 ms, params: {device: adc0}, "
                                "ports: {v: v2b},\n          resources: [{device: adc0, channels: [5, 6]}]}\n  drive:"),
                   ("  run: [force, aux, drive]", "  run: [aux, spare, drive]"),
                   ("  force: {module: ft_sensor, rtpu: rtpu1, period: 1 ms, params: {device: ft_b}, resources: [ft_b]}\n", ""),
                   ("  f_m: {type: float64, shape: [6]}\n", "")),
            "E603", "{device: adc0, channels: [5, 6]",
            r"device 'adc0': 'spare' \(line 17\) claims channels 5-6, but 'aux' \(line 15\) holds 6-7",
            hint=r"e\.g\. for 'spare': \{device: adc0, channels: 5\}$"),
    mistake("a_task_opening_a_port_based_device_whole_overlaps_every_subset",
            changed("[{device: dac0, channels: [0, 1]}]", "[dac0, {device: adc0, channels: 2}]"), "E603",
            "{device: adc0, channels: 2}]", r"device 'adc0': 'drive' \(line 19\) claims channels 2, but 'force'"),
    mistake("an_exclusive_device_used_through_a_sensor_and_directly_is_refused",
            changed("  adc0: {driver: adc}", "  adc0: {driver: adc, exclusive: true}"), "E601", "{device: adc0, channels: 6-7",
            r"device 'adc0' is exclusive, but configuration 'run' gives it to 'force' \(line 15, through device 'ft_b'\) "
            r"and 'aux' \(line 17\)$"),
    # malformed channel lists, reported at the list
    malformed_channels("a_reversed_channel_range", "7-6",
                       r"task 'aux': channels of device 'adc0': channel range '7-6' is reversed: write it low-high, e.g. '6-7'$"),
    malformed_channels("a_channel_listed_twice", "[6, 6]",
                       r"task 'aux': channels of device 'adc0': channel\(s\) 6 listed twice$"),
    malformed_channels("a_channel_that_is_not_a_number", "six",
                       r"task 'aux': channels of device 'adc0': a channel must be an integer or a range 'a-b', got: 'six'"),
    malformed_channels("an_empty_channel_list", "[]", r"task 'aux': channels of device 'adc0': the channel list is empty"),
    # channels a device does not have
    mistake("channels_a_device_does_not_have_are_an_error",
            changed("channels: 6-7}]", "channels: 7-9}]"), "E605", "adc0, channels: 7-9",
            r"task 'aux' opens channel\(s\) 8-9 of device 'adc0', which has channels 0-7 \(driver adc\)$",
            hint=r"^choose channels among 0-7$"),
    mistake("channels_of_a_device_that_is_not_port_based_are_an_error",
            changed("resources: [ft_b]", "resources: [{device: ft_b, channels: 0}]"), "E605", "ft_b, channels: 0",
            r"task 'force' opens channels 0 of device 'ft_b', but its driver ft_analog is not a port-based I/O device"),
    mistake("a_sensor_wired_to_too_few_channels_is_an_error",
            changed("{device: adc0, channels: 0-5}", "{device: adc0, channels: 0-3}"), "E605", "adc0, channels: 0-3",
            r"device 'ft_b' \(driver ft_analog\) needs 6 channels of its adc device, but io: gives 4 \(0-3\)$"),
    # wrong io wiring, reported at the io
    wrong_io("io_wired_to_an_undeclared_device",
             "{device: adc0, channels: 0-5}", "{device: adc9, channels: 0-5}", "adc9",
             r"device 'ft_b' is wired \(io:\) to device 'adc9', which 'devices' does not declare"),
    wrong_io("io_wired_to_a_device_of_the_wrong_kind",
             "{device: adc0, channels: 0-5}", "{device: pio0, channels: 0-5}", "pio0, channels: 0-5",
             r"device 'ft_b' \(driver ft_analog\) reads through a device of kind adc, "
             r"but its io: device 'pio0' is of kind parallel_port"),
    wrong_io("io_wired_to_a_device_that_is_not_an_io_device",
             "{device: adc0, channels: 0-5}", "{device: ft_a}", "ft_a}, calibration",
             r"device 'ft_b' \(driver ft_analog\) reads through a device of kind adc, "
             r"but its io: device 'ft_a' is not an I/O device"),
    wrong_io("io_given_to_a_driver_that_reads_no_io_device",
             "  dac0: {driver: dac}", "  dac0: {driver: dac, io: {device: adc0}}", "adc0}}",
             r"device 'dac0': driver dac reads no I/O device, so it takes no io:$"),
    mistake("a_sensor_without_its_io_is_an_error",
            changed("  ft_a: {driver: ft_parallel, io: {device: pio0, channels: 0-7}}", "  ft_a: {driver: ft_parallel}"), "E606",
            "ft_a: {driver: ft_parallel}",
            r"device 'ft_a' \(driver ft_parallel\) reads through a device of kind parallel_port, but it has no io:$",
            hint=r"^say where it is wired, e\.g\. io: \{device:"),
    mistake("sensors_wired_to_each_other_are_a_loop",
            changed("  ft_a: {driver: ft_parallel, io: {device: pio0, channels: 0-7}}",
                    "  ft_a: {driver: ft_parallel, io: {device: ft_a}}"),
            "E606", "ft_a}}", r"device 'ft_a' is wired \(io:\) to itself through ft_a$"),
    # driver options
    mistake("a_calibration_matrix_of_the_wrong_shape_is_an_error_at_the_option",
            changed("offset: [0, 0, 0, 0, 0, 0]}", "offset: [0, 0, 0]}"), "E607", "[0, 0, 0]}",
            r"device 'ft_b' \(driver ft_analog\): ft_analog option offset must be 6 voltages, got shape \(3,\)",
            hint=r"docstring lists its options"),
]


@pytest.mark.parametrize(("text", "code", "fragment", "message", "hint"), ONE_MISTAKE)
def test_one_mistake_is_reported_at_its_node_with_an_anchored_message(tmp_path, text, code, fragment, message, hint):
    error = expect(tmp_path, text, code, fragment, message)
    if hint is not None:
        assert re.search(hint, error.hint), error.hint


def test_claims_in_different_configurations_warn_that_a_dynamic_run_spawns_both(tmp_path):
    text = changed("channels: 6-7}]", "channels: 4-7}]")
    text = changed("v2:  {type: float64, shape: [2]}", "v2:  {type: float64, shape: [4]}", text)  # one element a channel
    text = changed("  run: [force, aux, drive]", "  run: [force, drive]\n  probe: [aux, drive]", text)
    warning = expect(tmp_path, text, "W601", "{device: adc0, channels: 4-7",
                     r"tasks 'force' \(line 15, through device 'ft_b'\) and 'aux' \(line 17\) both open device 'adc0' "
                     r"\(both need channels 4-5\); no configuration has both", warning=True)
    assert "--static" in warning.hint
    assert check(tmp_path, text).errors == []


@pytest.mark.parametrize(("resource", "code", "message"), [
    ("{device: adc0, chanels: 6-7}", "E111", r"unknown key 'chanels' in resource of task 'aux'"),
    ("{channels: 6-7}", "E112", r"resource of task 'aux' has no 'device:', which is required"),
    ("7", "E113",
     r"resource of task 'aux' must be a device name or a mapping \{device: \.\.\., channels: \.\.\.\}, got: the integer 7"),
])
def test_a_malformed_resource_says_what_a_resource_is(tmp_path, resource, code, message):
    text = changed("[{device: adc0, channels: 6-7}]", f"[{resource}]")
    result = check(tmp_path, text)
    assert any(e.code == code and re.search(message, e.message) for e in result.errors), [e.format() for e in result.errors]


def test_a_plain_device_name_still_works_as_a_resource(tmp_path):
    text = changed("[{device: dac0, channels: [0, 1]}]", "[dac0]")
    text = changed("  out: {type: float64, shape: [2], initial: 0}", "  out: {type: float64, shape: [4], initial: 0}", text)
    result = check(tmp_path, text)
    assert result.errors == [], [e.format() for e in result.errors]
    assert result.subsystem.tasks["drive"].resources == ("dac0",) and result.subsystem.tasks["drive"].resource_channels == {}
