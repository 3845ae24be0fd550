"""One way from any robot to the model the plant steps: a registered robot or a file, through MjSpec.

A robot registered by name (entry-point group `pbo.robots`: a function returning a DH
`RobotDescription`, or the path of a URDF or MJCF file) and a robot file named in the YAML take
the same road: an `MjSpec`, to which the plant's parts are added (site `ee` at the end effector;
the wrist force/torque sensor, body and site `ft` with sensors `ft_force` and `ft_torque`;
optionally the camera's target, mocap body `target`), compiled once. The arm's constants for the
controllers (`ARM`, `EE`) are then read from the compiled model, so they cannot disagree with it.

Every robot gets the plant's physics: its timestep, the `implicitfast` integrator, gravity
-9.81 m/s² along z, and no contacts (the controllers here do not model them). A file's own
actuators are removed, their force ranges kept as torque limits: the plant applies the joint
torques the robot interface commands, as a drive does.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from drivers.robots.arm_table import ArmTables
from drivers.robots.description import RobotDescription, limit_rows
from drivers.robots.files import RobotFileError, RobotSource, read_robot, resolve
from pbo_runtime import GRAVITY, Arm, is_robot_file, registered_robot

_LIMIT_OPTIONS = ("torque_limits", "velocity_limits", "joint_limits")
_RESERVED_SITES = ("ft", "target")
_RESERVED_BODIES = ("ft", "target")
_TARGET_RADIUS = 0.02  # the camera target's marker, for looks only (m)


@dataclass
class PlantRobot:
    """A robot ready for the plant: its compiled model and everything read from it."""

    name: str  # the model as the YAML names it
    source: str  # the file it came from, or "registered robot NAME"
    model: mujoco.MjModel
    joint_names: tuple[str, ...]
    ee_name: str  # the body or site the end effector is at
    q0: np.ndarray  # the braked start pose
    home: np.ndarray  # the robot's own start pose (q0 when the plant option does not give one)
    joint_limits: np.ndarray  # (n, 2); -inf and inf for a joint without a range
    torque_limits: np.ndarray  # (n,)
    velocity_limits: np.ndarray  # (n,), 0 where the robot gives none
    arm: np.ndarray  # the ARM constant
    ee: np.ndarray  # the EE constant
    notes: list[str] = field(default_factory=list)  # what was changed to load the file

    @property
    def ndof(self) -> int:
        return len(self.joint_names)

    @property
    def dims(self) -> dict[str, int]:
        return {"NDOF": self.ndof}

    def limit_rows(self) -> list[dict[str, object]]:
        """Each joint's limits as `pbo check` shows them (`description.limit_rows`): the ARM table's."""
        return limit_rows(self.joint_names, self.arm[:, Arm.TYPE] == Arm.SLIDE, self.torque_limits, self.velocity_limits,
                          self.joint_limits)


def load_robot(model: str, base_dir: Path, timestep: float, options: Mapping[str, Any], target: bool = False) -> PlantRobot:
    """The robot `model` names (a registered name, a path from `base_dir`, a `package://` URI),
    ready to step at `timestep`; RobotFileError (a ValueError) saying what is wrong and the fix."""
    if not timestep > 0:
        raise ValueError(f"plant timestep must be > 0, got: {timestep}")
    source, description, default_ee = _source(model, base_dir)
    spec = source.spec
    spec.modelname = spec.modelname or Path(model).stem
    spec.option.timestep = timestep
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.gravity = GRAVITY
    spec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    _check_joints(spec, source)
    actuator_limits = _remove_actuators(spec, source)
    ee_name = str(options.get("ee", default_ee or _last_body(spec, source)))
    _add_end_effector(spec, source, ee_name)
    _add_wrist_sensor(spec)
    if target:
        _add_target(spec)
    compiled = _compile(spec, source)
    names = tuple(compiled.joint(j).name or f"joint{j + 1}" for j in range(compiled.njnt))
    if not names:
        raise RobotFileError(f"{source.path.name} has no joints: there is no arm to move")
    torque = _torque_limits(compiled, names, actuator_limits, options, source)
    velocity = _velocity_limits(names, options, source)
    _tighten_ranges(compiled, names, options, source)
    limits = np.where(compiled.jnt_limited[:, None] > 0, compiled.jnt_range, [-np.inf, np.inf])
    home = _start_pose(compiled, spec, {}, description, limits, source)
    q0 = _start_pose(compiled, spec, options, description, limits, source) if "q0" in options else home
    tables = ArmTables(compiled, compiled.site("ee").id, torque, velocity)
    return PlantRobot(model, str(source.path) if description is None else f"registered robot {model}", compiled, names,
                      ee_name, q0, home, limits, torque, velocity, tables.arm, tables.ee, source.notes)


def _source(model: str, base_dir: Path) -> tuple[RobotSource, RobotDescription | None, str | None]:
    """The robot's spec, its DH description when it is one, and the end effector it names by default."""
    if is_robot_file(model):
        return read_robot(resolve(model, base_dir)), None, None
    try:
        made = registered_robot(model)
    except Exception as exc:
        raise RobotFileError(str(exc)) from None
    if isinstance(made, RobotDescription):
        from drivers.robots.mjcf import to_mjcf

        spec = mujoco.MjSpec.from_string(to_mjcf(made, 0.001))
        velocity = {
            f"joint{j + 1}": float(v)
            for j, v in enumerate(made.velocity_limits if made.velocity_limits is not None else ())
            if v > 0
        }
        return RobotSource(Path(f"{model}.xml"), spec, "mjcf", velocity=velocity), made, "ee"
    path = Path(str(made))
    return read_robot(path), None, None


def _check_joints(spec: mujoco.MjSpec, source: RobotSource) -> None:
    """Only hinge and slide joints, one a body: what the modules (and a serial drive) support."""
    supported = (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)
    for joint in spec.joints:
        if joint.type not in supported:
            kind = {mujoco.mjtJoint.mjJNT_FREE: "free", mujoco.mjtJoint.mjJNT_BALL: "ball"}.get(joint.type, str(joint.type))
            raise RobotFileError(
                f"joint {joint.name or '(unnamed)'!r} of {source.path.name} is a {kind} joint; the plant and the modules "
                "move fixed-base arms of hinge (revolute) and slide (prismatic) joints: fix the base to the world "
                "(remove the free joint) or make it revolute")
    for body in spec.bodies:
        if len(body.joints) > 1:
            raise RobotFileError(f"body {body.name!r} of {source.path.name} has {len(body.joints)} joints; "
                                 "give each joint a body of its own")


def _remove_actuators(spec: mujoco.MjSpec, source: RobotSource) -> dict[str, float]:
    """Remove the file's actuators; the torque limit each gave its joint (N m, or N)."""
    limits: dict[str, float] = {}
    actuators = list(spec.actuators)
    for actuator in actuators:
        gear = abs(float(actuator.gear[0])) or 1.0
        if actuator.forcelimited == mujoco.mjtLimited.mjLIMITED_TRUE or (actuator.forcerange[1] > actuator.forcerange[0]):
            limit = max(abs(actuator.forcerange[0]), abs(actuator.forcerange[1])) * gear
        elif actuator.ctrlrange[1] > actuator.ctrlrange[0] and actuator.biastype == mujoco.mjtBias.mjBIAS_NONE:
            limit = max(abs(actuator.ctrlrange[0]), abs(actuator.ctrlrange[1])) * gear  # a motor: ctrl is the force
        else:
            limit = 0.0
        if actuator.trntype == mujoco.mjtTrn.mjTRN_JOINT and actuator.target and limit > 0:
            limits[actuator.target] = limit
        spec.delete(actuator)
    if actuators:
        source.notes.append(f"removed {len(actuators)} actuator{'s' if len(actuators) > 1 else ''}: the plant applies "
                            "the robot interface's joint torques itself (their force ranges are kept as torque limits)")
    return limits


def _last_body(spec: mujoco.MjSpec, source: RobotSource) -> str:
    """The default end effector: the last body carried by the last joint, the tip of a serial arm."""
    joints = list(spec.joints)
    if not joints:
        raise RobotFileError(f"{source.path.name} has no joints: there is no arm to move")
    tip = joints[-1].parent
    while True:
        children = [body for body in tip.bodies]
        if not children:
            return str(tip.name)
        tip = children[-1]


def _add_end_effector(spec: mujoco.MjSpec, source: RobotSource, ee_name: str) -> None:
    """Site `ee` where the end effector is: at a site of that name, or at the origin of a body (link)."""
    site = _find(spec.sites, ee_name)
    body = _find(spec.bodies, ee_name)
    if site is None and body is None:
        known = [s.name for s in spec.sites if s.name] + [b.name for b in spec.bodies if b.name and b.name != "world"]
        close = difflib.get_close_matches(ee_name, known, n=1)
        raise RobotFileError(f"end effector {ee_name!r} is neither a link (body) nor a site of {source.path.name}"
                             + (f"; did you mean {close[0]!r}?" if close else "")
                             + f" (its last links and sites: {', '.join(known[-8:])})", key="ee")
    if site is not None and site.name == "ee":
        return
    if _find(spec.sites, "ee") is not None:
        raise RobotFileError(f"{source.path.name} has a site named 'ee' and the end effector is {ee_name!r}: "
                             "the plant names its end-effector site 'ee'; rename the file's site, or choose ee: ee", key="ee")
    if site is not None:
        parent = site.parent
        parent.add_site(name="ee", pos=site.pos, quat=site.quat, size=[0.01, 0.01, 0.01])
    else:
        body.add_site(name="ee", size=[0.01, 0.01, 0.01])


def _add_wrist_sensor(spec: mujoco.MjSpec) -> None:
    """Body `ft` (massless, no geoms) welded at the end effector, with the force/torque sensors on site `ft`."""
    ee = _find(spec.sites, "ee")
    for name in _RESERVED_BODIES:
        if _find(spec.bodies, name) is not None or _find(spec.sites, name) is not None:
            raise RobotFileError(f"the robot has a body or site named {name!r}, a name the plant's own parts use; rename it")
    body = ee.parent.add_body(name="ft", pos=ee.pos, quat=ee.quat)
    body.add_site(name="ft", size=[0.005, 0.005, 0.005])
    spec.add_sensor(name="ft_force", type=mujoco.mjtSensor.mjSENS_FORCE, objtype=mujoco.mjtObj.mjOBJ_SITE, objname="ft")
    spec.add_sensor(name="ft_torque", type=mujoco.mjtSensor.mjSENS_TORQUE, objtype=mujoco.mjtObj.mjOBJ_SITE, objname="ft")


def _add_target(spec: mujoco.MjSpec) -> None:
    """Mocap body `target`: a marker a camera sees, moved kinematically; it never touches the arm."""
    body = spec.worldbody.add_body(name="target", mocap=True)
    body.add_geom(name="target", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[_TARGET_RADIUS, 0, 0], contype=0, conaffinity=0,
                  rgba=[1, 0.3, 0.1, 0.8])
    body.add_site(name="target", size=[0.005, 0.005, 0.005])


def _find(elements: Any, name: str) -> Any:
    for element in elements:
        if element.name == name:
            return element
    return None


def _torque_limits(model: mujoco.MjModel, names: tuple[str, ...], actuators: dict[str, float],
                   options: Mapping[str, Any], source: RobotSource) -> np.ndarray:
    """Each joint's effort limit: the file's, or the plant option's where the file gives none or it is lower."""
    given = np.array([float(np.max(np.abs(model.jnt_actfrcrange[j]))) if model.jnt_actfrclimited[j] else actuators.get(name, 0.0)
                      for j, name in enumerate(names)])
    limits = _tightened(given, _per_joint(options, "torque_limits", names), "torque_limits", "N m", names, source)
    missing = [name for name, limit in zip(names, limits, strict=True) if not limit > 0]
    if missing:
        raise RobotFileError(
            f"{source.path.name} gives no torque limit for joint{'s' if len(missing) > 1 else ''} {', '.join(missing)}: "
            "give each joint one in the file (URDF <limit effort=...>, MJCF actuatorfrcrange or an actuator's "
            f"forcerange) or the plant option torque_limits: [{len(names)} values, N m]")
    return limits


def _velocity_limits(names: tuple[str, ...], options: Mapping[str, Any], source: RobotSource) -> np.ndarray:
    """Each joint's speed limit (0: none): the file's, or the plant option's where the file gives none or it is lower."""
    given = np.array([source.velocity.get(name, 0.0) for name in names])
    return _tightened(given, _per_joint(options, "velocity_limits", names), "velocity_limits", "rad/s", names, source)


def _tightened(given: np.ndarray, option: np.ndarray | None, key: str, unit: str, names: tuple[str, ...],
               source: RobotSource) -> np.ndarray:
    """The robot's limits `given` (0: none), tightened by the plant option `key`; RobotFileError where
    the option would widen one: a file may lower a limit the robot gives, never raise it."""
    if option is None:
        return given
    wider = [j for j in range(len(names)) if given[j] > 0 and option[j] > given[j]]
    if wider:
        listed = ", ".join(f"{names[j]} ({option[j]:g} > {given[j]:g} {unit})" for j in wider)
        raise RobotFileError(
            f"plant option {key} would widen the limit {source.path.name} gives for {listed}: a file may tighten "
            "the robot's limits, never widen them", key=key,
            hint=f"give at most the robot's own: [{', '.join(f'{g:g}' if g > 0 else '...' for g in given)}]")
    return option.copy()


def _tighten_ranges(model: mujoco.MjModel, names: tuple[str, ...], options: Mapping[str, Any], source: RobotSource) -> None:
    """The plant option joint_limits, [lower, upper] per joint, made the compiled model's ranges:
    within the file's range, never past it (a joint the file leaves unlimited takes any)."""
    if options.get("joint_limits") is None:
        return
    value = options["joint_limits"]
    try:
        ranges = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        ranges = np.zeros(0)
    if ranges.shape != (len(names), 2) or not np.all(np.isfinite(ranges)) or np.any(ranges[:, 0] >= ranges[:, 1]):
        raise RobotFileError(f"plant option joint_limits must be {len(names)} pairs [lower, upper] of finite numbers, lower < "
                             f"upper (rad, m for a slide joint; one per joint: {', '.join(names)}), got: {value!r}",
                             key="joint_limits")
    own = np.where(model.jnt_limited[:, None] > 0, model.jnt_range, [-np.inf, np.inf])
    wider = [j for j in range(len(names)) if ranges[j, 0] < own[j, 0] or ranges[j, 1] > own[j, 1]]
    if wider:
        listed = ", ".join(f"{names[j]} ([{ranges[j, 0]:g}, {ranges[j, 1]:g}] past [{own[j, 0]:.4g}, {own[j, 1]:.4g}])"
                           for j in wider)
        raise RobotFileError(f"plant option joint_limits would widen the range {source.path.name} gives for {listed}: a file may "
                             "tighten the robot's limits, never widen them", key="joint_limits",
                             hint="give each joint a range within the robot's own (pbo check lists them)")
    model.jnt_range[:] = ranges
    model.jnt_limited[:] = 1


def _per_joint(options: Mapping[str, Any], key: str, names: tuple[str, ...]) -> np.ndarray | None:
    if key not in options:
        return None
    value = options[key]
    try:
        array = np.array(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise RobotFileError(f"plant option {key} must be a list of {len(names)} numbers, got: {value!r}", key=key) from None
    if array.shape != (len(names),) or not np.all(np.isfinite(array)) or np.any(array <= 0):
        raise RobotFileError(f"plant option {key} must be {len(names)} finite numbers > 0 (one per joint: "
                             f"{', '.join(names)}), got: {value!r}", key=key)
    return array


def _start_pose(model: mujoco.MjModel, spec: mujoco.MjSpec, options: Mapping[str, Any], description: RobotDescription | None,
                limits: np.ndarray, source: RobotSource) -> np.ndarray:
    """The plant option q0; else the robot's home (a DH robot's, an MJCF keyframe 'home'); else zero, within range."""
    n = model.njnt
    if "q0" in options:
        try:
            q0 = np.array(options["q0"], dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise RobotFileError(
                f"plant option q0 must be a list of {n} numbers (rad), got: {options['q0']!r}", key="q0"
            ) from None
        if q0.shape != (n,):
            raise RobotFileError(f"plant option q0 must have {n} values for {source.path.name} "
                                 f"({', '.join(model.joint(j).name for j in range(n))}), got: {q0.size}", key="q0")
    elif description is not None:
        q0 = description.q0.copy()
    elif model.nkey and _find(spec.keys, "home") is not None:
        q0 = model.key("home").qpos.copy()
    else:
        q0 = np.clip(np.zeros(n), limits[:, 0], limits[:, 1])
    outside = [model.joint(j).name for j in range(n) if not limits[j, 0] <= q0[j] <= limits[j, 1]]
    if outside or not np.all(np.isfinite(q0)):
        raise RobotFileError(f"the start pose q0 is outside the range of joint{'s' if len(outside) > 1 else ''} "
                             f"{', '.join(outside)} of {source.path.name}, or not finite: give plant option q0 within range",
                             key="q0" if "q0" in options else "model")
    return q0


def _compile(spec: mujoco.MjSpec, source: RobotSource) -> mujoco.MjModel:
    """Compile; a mesh MuJoCo cannot decode is dropped with its geoms (and said), as an unreadable one is."""
    while True:
        try:
            return spec.compile()
        except ValueError as exc:
            mesh = _failed_mesh(spec, str(exc))
            if mesh is None:
                raise RobotFileError(f"MuJoCo cannot build {source.path.name}: {_compile_reason(exc)}") from None
            for geom in list(spec.geoms):
                if geom.meshname == mesh.name:
                    spec.delete(geom)
            source.notes.append(f"dropped mesh {Path(mesh.file).name}, which MuJoCo cannot decode: "
                                f"{_compile_reason(exc).split(';')[0]}")
            spec.delete(mesh)


def _failed_mesh(spec: mujoco.MjSpec, message: str) -> Any:
    """The mesh a compile error is about ("... Element name 'upper', id 0"), if it is one."""
    match = re.search(r"Element name '([^']*)'", message)
    if match is None or ("mesh" not in message.lower() and "stl" not in message.lower() and "obj" not in message.lower()):
        return None
    return _find(spec.meshes, match.group(1))


def _compile_reason(exc: ValueError) -> str:
    reason = " ".join(str(exc).replace("Error:", "").split())
    if "mass and inertia of moving bodies" in reason:
        reason += " (give that link an <inertial> with mass and inertia, or a geometry MuJoCo can read)"
    return reason
