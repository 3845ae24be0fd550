"""The device database (TR §4.6.1): exclusive devices locked, channel subsets lent, ownership in the table.

In one process, on a real table and a real plant's register segment, the database opens devices
for tasks as an RTPU does; one test opens a device from another process to show the ownership is
the table's, not the process's, and that a dead process's devices are recovered.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from drivers.io.adc import Adc
from drivers.mujoco_arm.plant import MujocoArmPlant
from drivers.mujoco_arm.registers import DeviceError
from modules.analog_input import AnalogInput
from pbo_runtime import DeviceDriver
from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.table.devices import DeviceBusyError, DeviceDatabase, DeviceOpenError
from pbo_runtime.table.table import StateTable, TableLayout, TaskState
from pbo_runtime.task.lifecycle import Task
from tests.support import NO_WATCHDOG, REPO, unique_name

SHEET = """\
    calibration: [[40.0, 0.8, -0.4, 0.0, 0.0, 0.2], [-0.6, 40.0, 0.5, 0.0, 0.0, -0.3], [0.4, -0.2, 80.0, 0.0, 0.0, 0.0],
                  [0.0, 0.02, 0.0, 4.0, 0.08, 0.0], [-0.02, 0.0, 0.0, -0.06, 4.0, 0.0], [0.0, 0.0, 0.01, 0.0, 0.0, 3.0]]
    offset: [0.012, -0.008, 0.025, 0.003, -0.004, 0.006]
"""

# Each task in its own configuration: the checker would refuse overlapping claims in one
# configuration (E603); here the database itself has to refuse them at open time.
SUBSYSTEM = f"""\
subsystem: devdb
rtpus: [rtpu0, rtpu1]
plant: {{model: puma560, timestep: 1 ms}}
devices:
  adc0: {{driver: adc}}
  dac_x: {{driver: dac, exclusive: true}}
  pio0: {{driver: parallel_port}}
  ft_a: {{driver: ft_parallel, io: {{device: pio0, channels: 0-7}}}}
  ft_b:
    driver: ft_analog
    io: {{device: adc0, channels: 0-5}}
{SHEET}
variables:
  v6: {{type: float64, shape: [6]}}
  v4: {{type: float64, shape: [4]}}
  v2: {{type: float64, shape: [2]}}
  v8: {{type: float64, shape: [8]}}
  f_m: {{type: float64, shape: [6]}}
  out_a: {{type: float64, shape: [2], initial: [1.0, 2.0]}}
  out_b: {{type: float64, shape: [2], initial: [3.0, 4.0]}}
tasks:
  low:     {{module: analog_input, rtpu: rtpu0, period: 1 ms, params: {{device: adc0}}, ports: {{v: v6}},
            resources: [{{device: adc0, channels: 0-5}}]}}
  high:    {{module: analog_input, rtpu: rtpu1, period: 1 ms, params: {{device: adc0}}, ports: {{v: v2}},
            resources: [{{device: adc0, channels: 6-7}}]}}
  middle:  {{module: analog_input, rtpu: rtpu1, period: 1 ms, params: {{device: adc0}}, ports: {{v: v4}},
            resources: [{{device: adc0, channels: 4-7}}]}}
  whole:   {{module: analog_input, rtpu: rtpu0, period: 1 ms, params: {{device: adc0}}, ports: {{v: v8}},
            resources: [adc0]}}
  force_a: {{module: ft_sensor, rtpu: rtpu0, period: 1 ms, params: {{device: ft_a}}, resources: [ft_a]}}
  force_b: {{module: ft_sensor, rtpu: rtpu1, period: 1 ms, params: {{device: ft_b}}, resources: [ft_b]}}
  out1:    {{module: analog_output, rtpu: rtpu0, period: 1 ms, params: {{device: dac_x}}, ports: {{v: out_a}},
            resources: [{{device: dac_x, channels: 0-1}}]}}
  out2:    {{module: analog_output, rtpu: rtpu1, period: 1 ms, params: {{device: dac_x}}, ports: {{v: out_b}},
            resources: [{{device: dac_x, channels: 2-3}}]}}
configurations:
  c_low: [low]
  c_high: [high]
  c_middle: [middle]
  c_whole: [whole]
  c_force_a: [force_a]
  c_force_b: [force_b]
  c_out1: [out1]
  c_out2: [out2]
"""


@pytest.fixture(scope="module")
def subsystem(tmp_path_factory):
    path = tmp_path_factory.mktemp("devdb") / "devdb.yaml"
    path.write_text(SUBSYSTEM)
    return load_subsystem(path)


@pytest.fixture
def plant() -> Iterator[MujocoArmPlant]:
    made = MujocoArmPlant(unique_name("plant"), "puma560", 0.001, {**NO_WATCHDOG, "wrist_wrench": [1.0, 2.0, 3.0, 0.1, 0.2, 0.3]})
    yield made
    made.close()


@pytest.fixture
def table(subsystem) -> Iterator[StateTable]:
    made = StateTable.create(TableLayout.of(subsystem), unique_name())
    yield made
    made.close()


class ClosingDatabase(DeviceDatabase):
    """The database, keeping what a test opened so that it is closed after the test."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.opened: list = []

    def open_for(self, device: str, task: str):
        driver = self.open(device, self.subsystem.tasks[task])
        self.opened.append(driver)
        return driver


@pytest.fixture
def database(subsystem, table, plant) -> Iterator[ClosingDatabase]:
    db = ClosingDatabase(subsystem, table, plant.name)
    yield db
    for driver in db.opened:
        driver.close()


def held(database: DeviceDatabase) -> set[tuple[str, str, str, tuple[int, ...]]]:
    return {(h.device, h.task, h.opened, h.channels) for h in database.holders()}


# --- channel subsets of a shared device ------------------------------------------------------------


def test_disjoint_channels_of_a_shared_adc_go_to_two_tasks_on_different_rtpus(database, plant):
    low = database.open_for("adc0", "low")
    high = database.open_for("adc0", "high")
    assert (low.channels, high.channels) == ((0, 1, 2, 3, 4, 5), (6, 7))
    assert held(database) == {("adc0", "low", "adc0", (0, 1, 2, 3, 4, 5)), ("adc0", "high", "adc0", (6, 7))}
    volts = np.zeros(6)
    low.read(volts)
    assert np.any(volts != 0)  # vendor B's gauges are on channels 0-5


def test_overlapping_channels_are_refused_naming_who_holds_which(database):
    database.open_for("adc0", "low")
    database.open_for("adc0", "high")
    pid = os.getpid()
    with pytest.raises(DeviceBusyError, match=(
            r"^task 'middle' cannot open channels 4-7 of device 'adc0': "
            rf"task 'low' \(RTPU rtpu0, pid {pid}\) holds channels 0-5; "
            rf"task 'high' \(RTPU rtpu1, pid {pid}\) holds channels 6-7; "
            r"they overlap on 4-7; a channel has one user at a time")):
        database.open_for("adc0", "middle")
    assert {h.task for h in database.holders()} == {"low", "high"}  # the refused opening left nothing behind


def test_opening_a_port_based_device_whole_takes_every_channel(database):
    database.open_for("adc0", "high")
    with pytest.raises(DeviceBusyError,
                       match=r"^task 'whole' cannot open channels 0-7 of device 'adc0': "
                             r"task 'high' .* holds channels 6-7; they overlap on 6-7"):
        database.open_for("adc0", "whole")


def test_closing_the_driver_releases_its_channels_for_the_next_task(database):
    high = database.open_for("adc0", "high")
    high.close()
    assert held(database) == set()
    middle = database.open_for("adc0", "middle")
    assert middle.channels == (4, 5, 6, 7)


# --- exclusive devices -----------------------------------------------------------------------------


def test_a_second_task_opening_an_exclusive_device_is_refused_naming_the_holder(database):
    database.open_for("dac_x", "out1")
    with pytest.raises(DeviceBusyError, match=(
            r"^task 'out2' cannot open channels 2-3 of device 'dac_x': the device is exclusive and "
            rf"task 'out1' \(RTPU rtpu0, pid {os.getpid()}\) holds channels 0-1; an exclusive device has one user at a time")):
        database.open_for("dac_x", "out2")


class SlowToClose(DeviceDriver):
    """Fake driver of 4 channels whose close waits (for a process's exit): the rest `close_now` returns."""

    PORTS = 4

    def close_now(self):
        return lambda: None


def test_a_driver_that_closes_in_two_steps_frees_its_device_for_the_next_task_before_the_rest_of_closing(subsystem, table):
    database = DeviceDatabase(subsystem, table, "registers", driver_lookup=lambda name: SlowToClose)
    first = database.open("dac_x", subsystem.tasks["out1"])
    rest = first.close_now()
    assert held(database) == set()  # released before the wait
    second = database.open("dac_x", subsystem.tasks["out2"])  # exclusive: refused if out1 still held it
    rest()
    assert {h.task for h in database.holders()} == {"out2"}
    second.close()


# --- sensors wired to I/O devices (TR §4.6.2) ------------------------------------------------------


def test_opening_a_sensor_takes_the_channels_it_is_wired_to(database):
    sensor = database.open_for("ft_b", "force_b")
    assert held(database) == {("ft_b", "force_b", "ft_b", ()), ("adc0", "force_b", "ft_b", (0, 1, 2, 3, 4, 5))}
    with pytest.raises(DeviceBusyError, match=r"^task 'middle' cannot open channels 4-7 of device 'adc0': task 'force_b' "
                                              r"\(RTPU rtpu1, pid \d+\) holds channels 0-5 through device 'ft_b'; "
                                              r"they overlap on 4-5"):
        database.open_for("adc0", "middle")
    database.open_for("adc0", "high")  # 6-7 are free
    sensor.close()
    assert {h.task for h in database.holders()} == {"high"}


def test_a_sensor_whose_io_channels_are_held_cannot_be_opened(database):
    database.open_for("adc0", "whole")
    with pytest.raises(DeviceBusyError,
                       match=r"^task 'force_b' cannot open device 'ft_b', wired to channels 0-5 of device 'adc0': "
                             r"task 'whole' .* holds channels 0-7"):
        database.open_for("ft_b", "force_b")


def test_a_sensor_driver_that_fails_to_open_releases_what_it_claimed(subsystem, table):
    database = DeviceDatabase(subsystem, table, unique_name("no-plant"))
    with pytest.raises(DeviceError, match=r"no register segment"):
        database.open("ft_b", subsystem.tasks["force_b"])
    assert database.holders() == []


# --- refusals before any claim ---------------------------------------------------------------------


def test_a_task_cannot_open_a_device_its_resources_do_not_list(database):
    with pytest.raises(DeviceOpenError, match=r"^task 'low' opens device 'pio0', but its resources are: adc0$"):
        database.open_for("pio0", "low")


def test_channels_beyond_the_device_or_on_a_device_without_channels_are_refused_at_open(subsystem, database):
    import dataclasses

    beyond = dataclasses.replace(subsystem.tasks["high"], resource_channels={"adc0": (7, 8)})
    with pytest.raises(DeviceOpenError, match=r"^device 'adc0' \(driver adc\) has channels 0-7; channel\(s\) 8 do not exist$"):
        database.open("adc0", beyond)
    sensor = dataclasses.replace(subsystem.tasks["force_b"], resource_channels={"ft_b": (0,)})
    with pytest.raises(DeviceOpenError, match=r"^device 'ft_b' \(driver ft_analog\) is not a port-based I/O device"):
        database.open("ft_b", sensor)
    assert database.holders() == []


# --- through a task's lifecycle, as an RTPU opens them ----------------------------------------------


def test_a_task_holds_its_channels_from_init_until_it_is_killed(subsystem, table, database):
    spec = subsystem.tasks["high"]
    task = Task(spec, AnalogInput, table, dict(subsystem.dims), dict(subsystem.devices),
                lambda device, opener: database.open(device.name, opener))
    assert task.spawn(0.0), task.last_error
    assert held(database) == {("adc0", "high", "adc0", (6, 7))}
    task.kill()
    assert task.state == TaskState.KILLED
    assert held(database) == set()


def test_a_refused_opening_fails_the_init_with_the_holders_name(subsystem, table, database):
    database.open_for("adc0", "low")
    task = Task(subsystem.tasks["middle"], AnalogInput, table, dict(subsystem.dims), dict(subsystem.devices),
                lambda device, opener: database.open(device.name, opener))
    assert not task.spawn(0.0)
    assert "init raised DeviceBusyError: task 'middle' cannot open channels 4-7 of device 'adc0': task 'low'" in task.last_error


def test_a_device_is_opened_only_in_an_init(subsystem, table, database):
    task = Task(subsystem.tasks["high"], AnalogInput, table, dict(subsystem.dims), dict(subsystem.devices),
                lambda device, opener: database.open(device.name, opener))
    assert task.spawn(0.0), task.last_error
    with pytest.raises(DeviceOpenError, match=r"^a device is opened in a task's init \(TR §4.6.1\); "
                                              r"task 'high' opened 'adc0' while OFF$"):
        task.open_device(subsystem.devices["adc0"])
    task.kill()


# --- ownership across processes --------------------------------------------------------------------

CHILD = """\
import sys
from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.table.devices import DeviceDatabase
from pbo_runtime.table.table import StateTable, TableLayout
sub = load_subsystem(sys.argv[1])
table = StateTable.attach(TableLayout.of(sub), sys.argv[2])
driver = DeviceDatabase(sub, table, sys.argv[3]).open("adc0", sub.tasks["high"])
print("opened", flush=True)
sys.stdin.readline()
"""


@pytest.mark.multiprocess
def test_channels_held_by_another_process_are_refused_and_recovered_when_it_dies(tmp_path, subsystem, table, plant, database):
    path = tmp_path / "devdb.yaml"
    path.write_text(SUBSYSTEM)
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(path), table.name, plant.name], cwd=REPO,
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "opened", child.stderr.read()
        with pytest.raises(DeviceBusyError, match=rf"task 'high' \(RTPU rtpu1, pid {child.pid}\) holds channels 6-7"):
            database.open_for("adc0", "middle")
        child.kill()  # the RTPU dies with the task: its devices must not stay locked
        child.wait(timeout=10)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
        child.stdin.close()
        child.stdout.close()
        child.stderr.close()
    middle = database.open_for("adc0", "middle")
    assert middle.channels == (4, 5, 6, 7)
    assert held(database) == {("adc0", "middle", "adc0", (4, 5, 6, 7))}


def test_the_table_layout_has_a_device_region_per_device(subsystem, table):
    assert table.devices.shape[0] == len(subsystem.devices) == 5
    without_devices = TableLayout.build(subsystem.variables.values(), len(subsystem.tasks))
    assert TableLayout.of(subsystem).total_bytes > without_devices.total_bytes
    assert not np.any(table.devices)


def test_a_table_whose_status_blocks_and_device_region_do_not_fill_whole_rows_still_maps(make_table):
    layout = TableLayout.build([], 5, 1)  # 5 x 16 status words + 40 device words: not a multiple of 16
    created = StateTable.create(layout, unique_name())
    try:
        assert created.status.shape == (5, 16) and created.devices.shape == (1, 8, 5)
    finally:
        created.close()


def test_the_adc_driver_refuses_channels_it_does_not_have(plant):
    with pytest.raises(DeviceError, match=r"^adc has channels 0-7; channel\(s\) 9 do not exist$"):
        Adc(plant.name, {}, channels=(0, 9))


def test_the_shipped_force_sensing_config_lends_the_adc_across_rtpus():
    sub = load_subsystem(REPO / "configs" / "force_sensing.yaml")
    assert sub.tasks["analog_in"].resource_channels == {"adc0": (6, 7)}
    assert sub.devices["ft_b"].io is not None and sub.devices["ft_b"].io.channels == (0, 1, 2, 3, 4, 5)
    assert sub.tasks["analog_in"].rtpu != sub.tasks["force_b"].rtpu
    assert Path(sub.file).name == "force_sensing.yaml"
