"""configs/force_sensing.yaml as a user runs it (TR §4.6): the F/T sensor on the running arm.

Each run starts the plant and two RTPUs for a second and a half of the simulated clock, so what
the sensors read never depends on how fast the machine is. The same task set runs
once with vendor A's sensor (parallel port) and once with vendor B's (ADC and calibration sheet):
both give the wrench the plant applies as f_m. The ADC is lent across RTPUs (vendor B's sensor
on channels 0-5 on rtpu1, the DAC loopback on 6-7 on rtpu0), and a task that asks for channels
another RTPU's task holds fails its init, naming the holder.
"""

from __future__ import annotations

import functools
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from drivers.force_torque import models
from drivers.mujoco_arm.registers import VOLTS_PER_COUNT
from tests.support import PBO, REPO, assert_nothing_left

pytestmark = pytest.mark.multiprocess

CONFIG = REPO / "configs" / "force_sensing.yaml"
DEMO = yaml.safe_load(CONFIG.read_text())
APPLIED = np.array(DEMO["plant"]["wrist_wrench"])
NOISE = DEMO["plant"]["adc_noise"]
# what each vendor resolves (see tests/test_force_torque.py): half a count of vendor A; half an ADC
# count through vendor B's calibration, plus 6 sigma of the ADC noise through it
A_BOUND = models.A_SCALE / 2
B_BOUND = (np.abs(models.CALIBRATION).sum(axis=1) * VOLTS_PER_COUNT / 2
           + 6 * NOISE * np.linalg.norm(models.CALIBRATION, axis=1))


def pbo_run(directory: Path, file: Path, *arguments: str) -> tuple[subprocess.CompletedProcess, dict]:
    report = directory / "report.json"
    done = subprocess.run([*PBO, "run", str(file), *arguments, "--report", str(report), "--no-live"],
                          cwd=directory, capture_output=True, text=True, timeout=180)
    return done, json.loads(report.read_text()) if report.exists() else {}


@functools.cache
def vendor_run(configuration: str, directory: str) -> dict:
    done, report = pbo_run(Path(directory), CONFIG, "--config", configuration, "--duration", "1.5", "--clock", "sim")
    assert done.returncode == 0, done.stderr
    return report


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, dict]:
    return {c: vendor_run(c, str(tmp_path_factory.mktemp(c))) for c in ("vendor_a", "vendor_b")}


@pytest.mark.parametrize(("configuration", "task", "bound"), [("vendor_a", "force_a", A_BOUND), ("vendor_b", "force_b", B_BOUND)])
def test_each_vendor_s_sensor_gives_the_applied_wrench_as_f_m(runs, configuration, task, bound):
    report = runs[configuration]
    assert report["stopped_by"] == "duration" and report["failure"] == ""
    f_m = report["variables"]["f_m"]
    assert f_m["writer"] == task
    assert np.all(np.abs(np.array(f_m["value"]) - APPLIED) <= bound), f_m["value"]
    assert report["states_at_stop"][task] == "ON"
    assert_nothing_left(report)


def test_the_two_vendors_give_the_same_f_m_for_the_same_contact(runs):
    f_a = np.array(runs["vendor_a"]["variables"]["f_m"]["value"])
    f_b = np.array(runs["vendor_b"]["variables"]["f_m"]["value"])
    print(f"\nforce_sensing.yaml, applied wrench {APPLIED.tolist()} (N, N m):")
    print(f"  vendor A f_m {np.array2string(f_a, precision=4)}")
    print(f"  vendor B f_m {np.array2string(f_b, precision=4)}")
    print(f"  |A - B| {np.array2string(np.abs(f_a - f_b), precision=4)}  "
          f"allowed {np.array2string(A_BOUND + B_BOUND, precision=4)}")
    assert np.all(np.abs(f_a - f_b) <= A_BOUND + B_BOUND)


def test_the_dac_drives_the_adc_channels_another_rtpu_was_lent(runs):
    for report in runs.values():
        v_in = report["variables"]["v_in"]
        assert v_in["writer"] == "analog_in"
        np.testing.assert_allclose(v_in["value"], DEMO["variables"]["v_out"]["initial"], atol=VOLTS_PER_COUNT + 6 * NOISE)


def test_a_task_asking_for_channels_held_on_another_rtpu_fails_its_init_naming_the_holders(tmp_path):
    config = yaml.safe_load(CONFIG.read_text())
    config["variables"]["v4"] = {"type": "float64", "shape": [4]}
    config["tasks"]["probe"] = {"module": "analog_input", "rtpu": "rtpu0", "period": "10 ms", "params": {"device": "adc0"},
                                "ports": {"v": "v4"}, "resources": [{"device": "adc0", "channels": "4-7"}]}
    config["configurations"]["probing"] = ["robot", "traj", "fk", "probe"]
    file = tmp_path / "probe.yaml"
    file.write_text(yaml.safe_dump(config, sort_keys=False))
    done, report = pbo_run(tmp_path, file, "--duration", "1", "--clock", "sim")
    assert done.returncode != 0
    assert "task 'probe' failed in init and was not created: init raised DeviceBusyError: task 'probe' cannot open " \
           "channels 4-7 of device 'adc0': task 'force_b' (RTPU rtpu1, pid " in done.stderr, done.stderr
    assert "holds channels 0-5 through device 'ft_b'; task 'analog_in' (RTPU rtpu0, pid " in done.stderr
    assert "Traceback" not in done.stderr
    assert_nothing_left(report)
