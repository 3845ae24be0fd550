"""The ros2_control side of an arm, over DDS, for the ros2_control driver's tests: a MuJoCo PUMA 560
stepped in real time (1 ms steps) in a process of its own, which publishes `/joint_states` (every
2 ms, as a joint_state_broadcaster) and applies the efforts of the newest
`/forward_effort_controller/commands` (a forward effort controller), clipped to the arm's limits;
with `--position`, it tracks the newest `/forward_position_controller/commands` with a drive's
position loop (critically damped at SERVO_OMEGA, gravity compensated, clipped to the limits).
Until the first command, and whenever none came for `COMMAND_TIMEOUT`, its brakes hold the arm.
Its message types are declared as ROS 2 declares them (tests/ros2_peer.py).

    python -m tests.ros2_control_peer DOMAIN SECONDS GOAL... [--silent-after S] [--position]

It prints one JSON line per event: `{"reached": t}` once the arm has stayed within 0.01 rad of
GOAL for 0.5 s, `{"silent": t}` when it stops publishing joint states (after S s from reaching),
then at the end `{"q": [...], "commands": n, "braked_at_end": bool}`.
"""

import json
import sys
import time
from pathlib import Path

import mujoco
import numpy as np
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from drivers.robots.plant_model import load_robot
from tests.ros2_peer import QOS, Float64MultiArray, Header, JointState, Time

TIMESTEP = 0.001
PUBLISH_EVERY = 2  # steps
COMMAND_TIMEOUT = 0.05  # s without a command before the brakes hold the arm
SERVO_OMEGA = 40.0  # rad/s, each joint's position loop in --position mode
REPO = Path(__file__).resolve().parent.parent


def main(argv: list[str]) -> None:
    silent_after = None
    position = "--position" in argv
    argv = [a for a in argv if a != "--position"]
    if "--silent-after" in argv:
        at = argv.index("--silent-after")
        silent_after = float(argv[at + 1])
        argv = argv[:at] + argv[at + 2:]
    domain, seconds, goal = int(argv[0]), float(argv[1]), np.array([float(v) for v in argv[2:]])
    robot = load_robot("puma560", REPO, TIMESTEP, {})
    model, data = robot.model, mujoco.MjData(robot.model)
    data.qpos[:] = robot.q0
    mujoco.mj_forward(model, data)
    limits = robot.torque_limits
    participant = DomainParticipant(domain)
    states = DataWriter(participant, Topic(participant, "rt/joint_states", JointState, qos=QOS), qos=QOS)
    controller = "forward_position_controller" if position else "forward_effort_controller"
    commands = DataReader(participant, Topic(participant, f"rt/{controller}/commands", Float64MultiArray, qos=QOS), qos=QOS)
    inertia = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, inertia)
    servo_kp, servo_kd = np.diag(inertia) * SERVO_OMEGA**2, 2.0 * np.diag(inertia) * SERVO_OMEGA
    q_cmd = data.qpos.copy()
    message = JointState(header=Header(stamp=Time(sec=0, nanosec=0), frame_id=""), name=list(robot.joint_names),
                         position=[], velocity=[], effort=[])
    tau = np.zeros(model.nv)
    brake_pose = data.qpos.copy()
    last_command_at, received, braked = -1.0, 0, True
    within_since, reached_at, silent = None, None, False
    start = time.monotonic()
    step = 0
    while (now := time.monotonic() - start) < seconds:
        for sample in commands.take(N=16):
            if isinstance(sample, Float64MultiArray) and len(sample.data) == model.nv:
                if position:
                    q_cmd[:] = sample.data
                else:
                    tau[:] = np.clip(sample.data, -limits, limits)
                last_command_at = now
                received += 1
        if position:
            tau[:] = np.clip(servo_kp * (q_cmd - data.qpos) - servo_kd * data.qvel + data.qfrc_bias, -limits, limits)
        should_brake = last_command_at < 0 or now - last_command_at > COMMAND_TIMEOUT
        if should_brake and not braked:
            brake_pose[:] = data.qpos
        braked = should_brake
        data.qfrc_applied[:] = 0.0 if braked else tau
        mujoco.mj_step(model, data)
        if braked:
            data.qpos[:] = brake_pose
            data.qvel[:] = 0.0
        step += 1
        if step % PUBLISH_EVERY == 0 and not silent:
            stamp = time.time_ns()
            message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
            message.position, message.velocity = data.qpos.tolist(), data.qvel.tolist()
            message.effort = data.qfrc_applied.tolist()
            states.write(message)
        if reached_at is None:
            if np.abs(data.qpos - goal).max() < 0.01:
                within_since = now if within_since is None else within_since
                if now - within_since >= 0.5:
                    reached_at = now
                    print(json.dumps({"reached": now, "q": data.qpos.tolist()}), flush=True)
            else:
                within_since = None
        elif silent_after is not None and not silent and now - reached_at >= silent_after:
            silent = True
            print(json.dumps({"silent": now}), flush=True)
        ahead = step * TIMESTEP - (time.monotonic() - start)
        if ahead > 0:
            time.sleep(ahead)
    print(json.dumps({"q": data.qpos.tolist(), "commands": received, "braked_at_end": braked}), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
