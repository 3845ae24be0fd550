"""The simulated I/O boards (TR §4.6.1): an ADC, a DAC and a parallel port, served by the plant.

In one process: the plant is stepped by hand; the drivers attach to its register segment with the
channels the device database would lend them.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from drivers.io.adc import Adc
from drivers.io.dac import Dac
from drivers.io.parallel_port import ParallelPort
from drivers.mujoco_arm.plant import MujocoArmPlant
from drivers.mujoco_arm.registers import VOLTS_PER_COUNT, W_BOARD_STEP, W_STEP_COUNT, DeviceError, attach_registers
from pbo_runtime.supervisor.plant_host import _has_boards
from tests.support import NO_WATCHDOG, allocation_peak, one_array, unique_name


@pytest.fixture
def plant() -> Iterator[MujocoArmPlant]:
    made = MujocoArmPlant(unique_name("plant"), "puma560", 0.001, NO_WATCHDOG)
    yield made
    made.close()


@pytest.fixture
def opened() -> Iterator[list]:
    drivers: list = []
    yield drivers
    for driver in drivers:
        driver.close()


def test_the_dac_is_looped_back_to_adc_channels_6_and_7(plant, opened):
    dac = Dac(plant.name, {}, channels=(0, 1))
    adc = Adc(plant.name, {}, channels=(6, 7))
    opened += [dac, adc]
    dac.write(np.array([2.5, -7.3]))
    volts = np.zeros(2)
    before = adc.read(volts)
    np.testing.assert_array_equal(volts, 0.0)  # not converted yet
    plant.step()
    assert adc.read(volts) == before + 1  # the plant step of the conversion
    np.testing.assert_allclose(volts, [2.5, -7.3], atol=VOLTS_PER_COUNT)


def test_the_adc_reads_channels_that_are_not_consecutive_in_channel_order(plant, opened):
    dac = Dac(plant.name, {}, channels=(0, 1))
    opened.append(dac)
    dac.write(np.array([1.0, -2.0]))
    plant.step()
    scattered = Adc(plant.name, {}, channels=(0, 6, 7))
    every = Adc(plant.name, {})
    opened += [scattered, every]
    assert not scattered.contiguous and every.channels == tuple(range(8))
    all_volts, some = np.zeros(8), np.zeros(3)
    every.read(all_volts)
    scattered.read(some)
    np.testing.assert_array_equal(some, all_volts[[0, 6, 7]])
    counts = np.zeros(3, dtype=np.int16)
    scattered.read_counts(counts)
    np.testing.assert_array_equal(counts * VOLTS_PER_COUNT, some)


def test_a_dac_writes_only_its_channels_clips_at_full_scale_and_returns_them_to_zero_when_closed(plant):
    low = Dac(plant.name, {}, channels=(0, 2))
    high = Dac(plant.name, {}, channels=(1, 3))
    try:
        high.write(np.array([4.0, 5.0]))
        low.write(np.array([20.0, -20.0]))
        registers = attach_registers(plant.name)
        try:
            np.testing.assert_allclose(registers.dac * VOLTS_PER_COUNT,
                                       [10.0 - VOLTS_PER_COUNT, 4.0, -10.0, 5.0], atol=VOLTS_PER_COUNT)
            low.close()
            np.testing.assert_allclose(registers.dac * VOLTS_PER_COUNT, [0.0, 4.0, 0.0, 5.0], atol=VOLTS_PER_COUNT)
        finally:
            registers.release()
    finally:
        low.close()
        high.close()


def test_a_parallel_port_drives_and_reads_the_lines_of_its_channels_by_position(plant, opened):
    port = ParallelPort(plant.name, {}, channels=(8, 9, 12))
    opened.append(port)
    port.write_channel(2, 0xBEEF)
    assert port.output(2) == 0xBEEF
    registers = attach_registers(plant.name)
    try:
        assert registers.pio_out[12] == 0xBEEF and not np.any(np.delete(registers.pio_out, 12))
        registers.pio_in[9] = 0x1234
        assert port.read_channel(1) == 0x1234
        lines = np.zeros(3, dtype=np.uint16)
        port.read(lines)
        np.testing.assert_array_equal(lines, [0, 0x1234, 0])
    finally:
        registers.release()


def test_vendor_a_s_sensor_shows_power_on_parallel_port_channel_7(plant, opened):
    port = ParallelPort(plant.name, {}, channels=tuple(range(8)))
    opened.append(port)
    assert port.read_channel(7) & 1


@pytest.mark.parametrize(("driver", "options", "channels", "message"), [
    (Adc, {"range": 5}, None, r"^unknown adc option\(s\) \['range'\]; valid options: none$"),
    (Dac, {}, (4,), r"^dac has channels 0-3; channel\(s\) 4 do not exist$"),
    (ParallelPort, {}, (), r"no channels to open$"),
])
def test_a_board_driver_refuses_what_its_board_does_not_have(plant, driver, options, channels, message):
    with pytest.raises((ValueError, DeviceError), match=message):
        driver(plant.name, options, channels=channels)


def test_one_small_array_per_call_would_show_in_the_allocation_peak():
    assert allocation_peak(lambda: np.empty(3)) >= 64
    assert one_array() > allocation_peak(lambda: None) + 64


def test_reading_the_adc_and_writing_the_dac_allocate_nothing(plant, opened):
    adc = Adc(plant.name, {}, channels=(0, 3, 6))
    dac = Dac(plant.name, {}, channels=(0, 1))
    consecutive = Adc(plant.name, {}, channels=(6, 7))
    opened += [adc, dac, consecutive]
    volts, two, out = np.zeros(3), np.zeros(2), np.array([1.0, 2.0])

    for call in (lambda: adc.read(volts), lambda: consecutive.read(two), lambda: dac.write(out)):
        assert allocation_peak(call) < one_array()


# issue 18: a NaN voltage was cast to an arbitrary count; it is refused and the channels keep their value
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_dac_refuses_voltages_that_are_not_finite_and_writes_nothing(plant, opened, bad):
    dac = Dac(plant.name, {}, channels=(0, 1))
    opened.append(dac)
    dac.write(np.array([2.5, -1.0]))
    before = attach_registers(plant.name)
    try:
        counts = before.dac[:2].copy()
        with pytest.raises(DeviceError, match=rf"^dac on registers '{plant.name}': refused voltages that are not finite "
                                              rf"\(\[2\.5, -?(nan|inf)\]\) for channels \[0, 1\]; "
                                              r"the channels keep their values"):
            dac.write(np.array([2.5, bad]))
        np.testing.assert_array_equal(before.dac[:2], counts)
    finally:
        before.release()


@pytest.mark.parametrize("lines", [float("nan"), 1.5, -1, 65536, "3"])
def test_a_parallel_port_refuses_output_lines_that_are_not_16_bit_integers(plant, opened, lines):
    port = ParallelPort(plant.name, {}, channels=(2,))
    opened.append(port)
    port.write_channel(0, 0x00FF)
    with pytest.raises(DeviceError, match=rf"^parallel_port on registers '{plant.name}': output lines of channel 2 must be "
                                          rf"an integer 0 \.\. 65535, got: "):
        port.write_channel(0, lines)
    assert port.output(0) == 0x00FF


def test_a_plant_told_there_is_no_board_steps_without_converting():
    plant = MujocoArmPlant(unique_name("plant"), "puma560", 0.001, NO_WATCHDOG, boards=False)
    registers = attach_registers(plant.name)
    try:
        converted = int(registers.words[W_BOARD_STEP])
        for _ in range(3):
            plant.step()
        assert registers.words[W_STEP_COUNT] == 3  # the state is published every step
        assert registers.words[W_BOARD_STEP] == converted  # the boards are not converted
    finally:
        registers.release()
        plant.close()


@pytest.mark.parametrize(("drivers", "boards"), [
    ("mujoco_arm", False),
    ("", False),
    ("adc,mujoco_arm", True),
    ("dac", True),
    ("parallel_port", True),
    (None, True),  # not told (a plant host started by hand): served
    ("no_such_driver", True),  # its task reports it; the plant does not guess
])
def test_the_plant_host_serves_the_boards_only_when_a_device_is_a_board(drivers, boards):
    assert _has_boards(drivers) is boards
