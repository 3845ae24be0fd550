"""The wrist force/torque sensor from two vendors (TR §4.6.2): the same f_m for the same contact.

In one process: the plant applies a known wrench at the wrist (MuJoCo's xfrc_applied on the
massless `ft` body) and serves it raw through the boards; vendor A's driver reads 16-bit counts
through the parallel port with a strobe/ACK handshake, vendor B's reads six gauge voltages through
the ADC and applies its calibration sheet. Both must give the applied wrench, within what each
interface can resolve.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

import mujoco
import numpy as np
import pytest
import yaml

from drivers.force_torque import models
from drivers.force_torque.analog import AnalogForceTorque
from drivers.force_torque.parallel import ParallelForceTorque
from drivers.io.adc import Adc
from drivers.io.parallel_port import ParallelPort
from drivers.mujoco_arm.plant import MujocoArmPlant
from drivers.mujoco_arm.registers import VOLTS_PER_COUNT, W_BRAKE, DeviceError
from drivers.robots.plant_model import load_robot
from modules.ft_sensor import FtSensor
from pbo_runtime.task.lifecycle import Task
from tests.support import NO_WATCHDOG, REPO, allocation_peak, example_robot, one_array, task_spec, unique_name, variables

WRENCH = [12.0, -7.5, 30.0, 0.8, -0.45, 0.3]
SHEET = {"calibration": models.CALIBRATION.tolist(), "offset": models.OFFSET.tolist()}

# What each interface resolves, per axis (Fx Fy Fz in N, Tx Ty Tz in N m):
# vendor A rounds to a count: half a count of its fixed scale.
A_RESOLUTION = models.A_SCALE / 2
# vendor B rounds each gauge voltage to half an ADC count; its calibration mixes the six.
B_RESOLUTION = np.abs(models.CALIBRATION).sum(axis=1) * VOLTS_PER_COUNT / 2


def b_noise_bound(sigma: float, k: float = 6.0) -> np.ndarray:
    """k standard deviations of vendor B's wrench for ADC noise sigma (V) on each gauge."""
    return k * sigma * np.linalg.norm(models.CALIBRATION, axis=1)


@pytest.fixture
def make_plant() -> Iterator:
    made: list[MujocoArmPlant] = []

    def make(**options) -> MujocoArmPlant:
        plant = MujocoArmPlant(unique_name("plant"), "puma560", 0.001, {**NO_WATCHDOG, **options})
        made.append(plant)
        return plant

    yield make
    for plant in made:
        plant.close()


@pytest.fixture
def opened() -> Iterator[list]:
    drivers: list = []
    yield drivers
    for driver in drivers:
        driver.close()


def vendor_a(plant: MujocoArmPlant, opened: list, channels=tuple(range(8)), **options) -> ParallelForceTorque:
    port = ParallelPort(plant.name, {}, channels=channels)
    try:
        sensor = ParallelForceTorque(plant.name, options, io=port)
    except BaseException:
        port.close()
        raise
    opened.append(sensor)
    return sensor


def vendor_b(plant: MujocoArmPlant, opened: list, options=None) -> AnalogForceTorque:
    adc = Adc(plant.name, {}, channels=tuple(range(6)))
    try:
        sensor = AnalogForceTorque(plant.name, SHEET if options is None else options, io=adc)
    except BaseException:
        adc.close()
        raise
    opened.append(sensor)
    return sensor


# --- the physics --------------------------------------------------------------------------------


@pytest.mark.parametrize(("model", "wrist"), [("puma560", "link6"), (example_robot("ur5"), "tool0")])
def test_the_wrist_carries_a_massless_sensor_body_with_force_and_torque_sensors(model, wrist):
    """The plant adds the sensor to every robot it loads, a registered one or a robot file."""
    model = load_robot(model, REPO, 0.001, {}).model
    body = model.body("ft")
    assert model.body_mass[body.id] == 0.0 and model.body_parentid[body.id] == model.body(wrist).id
    assert model.site("ee").bodyid[0] == model.body(wrist).id  # welded where the end effector is
    assert [model.sensor(i).name for i in range(model.nsensor)] == ["ft_force", "ft_torque"]
    data = mujoco.MjData(model)
    data.qpos[:] = np.random.default_rng(6).uniform(-1, 1, model.nq)
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(data.site_xpos[model.site("ft").id], data.site_xpos[model.site("ee").id], atol=1e-12)
    np.testing.assert_allclose(data.site_xmat[model.site("ft").id], data.site_xmat[model.site("ee").id], atol=1e-12)


def test_the_plant_measures_exactly_the_applied_wrench_while_the_arm_falls(make_plant):
    plant = make_plant(wrist_wrench=WRENCH)
    plant._registers.words[W_BRAKE] = 0  # no controller: the arm falls under gravity and the wrench
    for _ in range(200):
        plant.step()
        np.testing.assert_allclose(plant.measured_wrench, WRENCH, rtol=0, atol=1e-9)
    assert np.max(np.abs(plant.data.qvel)) > 0.1  # it did move


def test_without_a_contact_the_sensor_reads_nothing(make_plant):
    plant = make_plant()
    plant.step()
    np.testing.assert_array_equal(plant.measured_wrench, 0.0)


def test_a_bad_wrist_wrench_is_refused_saying_what_it_must_be(make_plant):
    with pytest.raises(ValueError,
                       match=r"^plant option wrist_wrench must be 6 finite numbers \[fx, fy, fz, tx, ty, tz\] \(N, N m\), "
                             r"got: \[1, 2\]$"):
        make_plant(wrist_wrench=[1, 2])


# --- vendor A: parallel port, strobe and ACK ---------------------------------------------------------


def test_vendor_a_reads_the_applied_wrench_within_half_a_count(make_plant, opened):
    plant = make_plant(wrist_wrench=WRENCH)
    sensor = vendor_a(plant, opened)
    f_m = np.zeros(6)
    assert not sensor.read_wrench(f_m)  # requested at open; the sensor answers at the plant's next step
    np.testing.assert_array_equal(f_m, 0.0)
    plant.step()
    assert sensor.read_wrench(f_m)
    assert np.all(np.abs(f_m - WRENCH) <= A_RESOLUTION + 1e-12)
    assert not sensor.read_wrench(f_m)  # no new answer until the plant steps: the last reading is kept
    assert np.all(np.abs(f_m - WRENCH) <= A_RESOLUTION + 1e-12)
    plant.set_wrist_wrench([0.0, 0.0, -5.0, 0.0, 0.0, 0.0])
    plant.step()
    plant.step()
    assert sensor.read_wrench(f_m)
    np.testing.assert_allclose(f_m, [0, 0, -5.0, 0, 0, 0], atol=1e-12)
    assert sensor.readings == 2 and not sensor.clipped


def test_vendor_a_marks_a_reading_beyond_its_full_scale_as_clipped(make_plant, opened):
    plant = make_plant(wrist_wrench=[0, 0, 0, 0, 0, 20.0])  # 16.4 N m full scale
    sensor = vendor_a(plant, opened)
    f_m = np.zeros(6)
    plant.step()
    assert sensor.read_wrench(f_m) and sensor.clipped
    assert f_m[5] == pytest.approx(32767 * models.TORQUE_PER_COUNT)


def test_vendor_a_on_channels_where_its_cable_is_not_is_refused(make_plant, opened):
    plant = make_plant()
    with pytest.raises(DeviceError,
                       match=r"no vendor A force/torque sensor answers on parallel-port channels "
                             r"\[8, 9, 10, 11, 12, 13, 14, 15\]"):
        vendor_a(plant, opened, channels=tuple(range(8, 16)))


def test_vendor_a_gives_up_when_its_sensor_stops_answering(make_plant, opened):
    plant = make_plant()
    sensor = vendor_a(plant, opened, timeout=1e-6)
    f_m = np.zeros(6)
    with pytest.raises(DeviceError, match=r"^vendor A force/torque sensor: no answer to request \d+ for over 1e-06 s"):
        for _ in range(1_000_000):  # the plant is never stepped
            sensor.read_wrench(f_m)


# --- vendor B: ADC and calibration sheet ------------------------------------------------------------


def test_vendor_b_reads_the_applied_wrench_within_its_adc_resolution(make_plant, opened):
    plant = make_plant(wrist_wrench=WRENCH)
    sensor = vendor_b(plant, opened)
    f_m = np.zeros(6)
    assert sensor.read_wrench(f_m)  # the plant converted at start
    assert np.all(np.abs(f_m - WRENCH) <= B_RESOLUTION + 1e-12), f_m - WRENCH
    assert not sensor.read_wrench(f_m)  # the same conversion again
    plant.step()
    assert sensor.read_wrench(f_m)


def test_vendor_b_with_another_sensor_s_calibration_sheet_reads_wrong(make_plant, opened):
    plant = make_plant(wrist_wrench=WRENCH)
    sensor = vendor_b(plant, opened, {"calibration": np.eye(6).tolist(), "offset": [0.0] * 6})
    f_m = np.zeros(6)
    sensor.read_wrench(f_m)
    assert np.max(np.abs(f_m - WRENCH)) > 1.0  # the sheet is what turns volts into newtons


@pytest.mark.parametrize(("options", "message"), [
    ({"offset": [0.0] * 6}, r"^ft_analog needs option\(s\) calibration: the sensor's calibration sheet"),
    ({**SHEET, "calibration": [[1.0] * 6] * 5},
     r"^ft_analog option calibration must be a 6x6 matrix \(6 rows of 6 numbers\), got shape \(5, 6\)"),
    ({**SHEET, "calibration": [[1.0] * 6] * 5 + [[1.0] * 5]}, r"^ft_analog option calibration must be a 6x6 matrix"),
    ({**SHEET, "offset": [0.0] * 5}, r"^ft_analog option offset must be 6 voltages, got shape \(5,\)"),
    ({**SHEET, "offset": ["a"] * 6}, r"^ft_analog option offset must be 6 voltages, got: \['a'"),
    ({**SHEET, "calibration": [[1.0] * 6] * 6}, r"^ft_analog option calibration is singular"),
    ({**SHEET, "gain": 2}, r"^unknown ft_analog option\(s\) \['gain'\]; valid options: calibration, offset$"),
])
def test_a_bad_calibration_sheet_says_what_is_wrong(make_plant, opened, options, message):
    with pytest.raises(ValueError, match=message):
        AnalogForceTorque.check_options(options)
    with pytest.raises(ValueError, match=message):
        vendor_b(make_plant(), opened, options)


def test_a_sensor_driver_without_the_io_device_it_reads_through_is_refused(make_plant, opened):
    plant = make_plant()
    adc = Adc(plant.name, {}, channels=tuple(range(6)))
    opened.append(adc)
    with pytest.raises(DeviceError, match=r"^ft_parallel needs a parallel port"):
        ParallelForceTorque(plant.name, {}, io=adc)
    with pytest.raises(DeviceError, match=r"^ft_analog needs an ADC"):
        AnalogForceTorque(plant.name, SHEET, io=None)
    short = Adc(plant.name, {}, channels=(0, 1, 2, 3))
    opened.append(short)
    with pytest.raises(DeviceError, match=r"^ft_analog needs 6 ADC channels, got 4$"):
        AnalogForceTorque(plant.name, SHEET, io=short)


# --- the same f_m from both ------------------------------------------------------------------------


def test_the_two_vendors_give_the_same_f_m_for_the_same_contact(make_plant, opened):
    """Issue 5: both equal the applied wrench within their resolution (and vendor B's 0.5 mV noise)."""
    sigma = 0.0005
    plant = make_plant(wrist_wrench=WRENCH, adc_noise=sigma, seed=3)
    a, b = vendor_a(plant, opened), vendor_b(plant, opened)
    rng = np.random.default_rng(5)
    f_a, f_b = np.zeros(6), np.zeros(6)
    worst_a, worst_b, worst_ab = np.zeros(6), np.zeros(6), np.zeros(6)
    for _ in range(50):
        applied = rng.uniform(-1, 1, 6) * [200, 200, 400, 10, 10, 10]  # within both sensors' ranges
        plant.set_wrist_wrench(applied)
        plant.step()  # the contact acts; vendor A answers the pending request
        a.read_wrench(f_a)
        plant.step()  # ...and the next one
        assert a.read_wrench(f_a) and b.read_wrench(f_b)
        worst_a = np.maximum(worst_a, np.abs(f_a - applied))
        worst_b = np.maximum(worst_b, np.abs(f_b - applied))
        worst_ab = np.maximum(worst_ab, np.abs(f_a - f_b))
    bound_b = B_RESOLUTION + b_noise_bound(sigma)
    print("\nF/T vendors, 50 contacts, worst |error| per axis (Fx Fy Fz N, Tx Ty Tz N m):")
    print(f"  vendor A (parallel port) vs applied: {np.array2string(worst_a, precision=5)}  "
          f"bound {np.array2string(A_RESOLUTION, precision=5)}")
    print(f"  vendor B (ADC, 0.5 mV noise) vs applied: {np.array2string(worst_b, precision=5)}  "
          f"bound {np.array2string(bound_b, precision=5)}")
    print(f"  |vendor A - vendor B|: {np.array2string(worst_ab, precision=5)}")
    assert np.all(worst_a <= A_RESOLUTION + 1e-12)
    assert np.all(worst_b <= bound_b)
    assert np.all(worst_ab <= A_RESOLUTION + bound_b)


def test_reading_a_wrench_allocates_nothing(make_plant, opened):
    plant = make_plant(wrist_wrench=WRENCH)
    a, b = vendor_a(plant, opened), vendor_b(plant, opened)
    f_a, f_b = np.zeros(6), np.zeros(6)
    registers = plant._registers

    requests, answers = memoryview(registers.pio_out), memoryview(registers.pio_in)

    def read_a():
        answers[models.A_ACK] = requests[models.A_REQUEST]  # the sensor answers at once
        a.read_wrench(f_a)

    try:
        assert allocation_peak(read_a) < one_array()
        assert allocation_peak(lambda: b.read_wrench(f_b)) < one_array()
        assert a.readings > 1000
    finally:
        requests.release()
        answers.release()


# --- the module ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("vendor", ["a", "b"])
def test_the_ft_sensor_module_outputs_f_m_whichever_vendor_it_opens(make_plant, opened, make_table, vendor):
    plant = make_plant(wrist_wrench=WRENCH)
    sensor = (vendor_a if vendor == "a" else vendor_b)(plant, opened)
    table = make_table(variables(("f_m", "float64", (6,))), 1)
    spec = dataclasses.replace(task_spec(FtSensor, params={"device": "ft"}), resources=("ft",))
    task = Task(spec, FtSensor, table, {}, {"ft": None}, lambda device, opener: sensor)
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0)
    plant.step()
    for _ in range(3):
        task.run_cycle(0.001)
        plant.step()
    value, *_ = table.read("f_m")
    assert np.all(np.abs(value - WRENCH) <= np.maximum(A_RESOLUTION, B_RESOLUTION) + 1e-12)
    assert task.module.fresh >= 2


def test_the_ft_sensor_module_refuses_a_device_that_is_no_force_sensor(make_plant, opened, make_table):
    plant = make_plant()
    adc = Adc(plant.name, {})
    opened.append(adc)
    table = make_table(variables(("f_m", "float64", (6,))), 1)
    spec = dataclasses.replace(task_spec(FtSensor, params={"device": "adc0"}), resources=("adc0",))
    task = Task(spec, FtSensor, table, {}, {"adc0": None}, lambda device, opener: adc)
    assert not task.spawn(0.0)
    assert ("device 'adc0' is not a force/torque sensor (its driver has no read_wrench); "
            "give it driver: ft_parallel or ft_analog") in task.last_error


def test_the_shipped_calibration_sheet_in_the_config_is_the_plant_s_sensor():
    config = yaml.safe_load((REPO / "configs" / "force_sensing.yaml").read_text())
    device = config["devices"]["ft_b"]
    np.testing.assert_array_equal(device["calibration"], models.CALIBRATION)
    np.testing.assert_array_equal(device["offset"], models.OFFSET)
