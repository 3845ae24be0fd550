"""Robot files as engineers bring them: a URDF or an MJCF read into a MuJoCo `MjSpec`, messes and all.

Real robot files name meshes by `package://` URIs, in formats MuJoCo cannot read (`.dae`), and
carry tags for other simulators. A file loads anyway, and `notes` says what was changed:

- `package://NAME/rest` is found in the file's own tree (a directory named NAME, or one whose
  `package.xml` names it), then in the search path: `PBO_ROBOT_PATH`, `ROS_PACKAGE_PATH` and
  `AMENT_PREFIX_PATH` (their `share/NAME`), and the `share/NAME` of Python packages built with
  cmeel (how pip ships ROS packages such as example-robot-data).
- A visual mesh MuJoCo cannot read is dropped (the collision mesh stands in for it); a collision
  mesh it cannot read, or that is missing, is dropped too, and a link left with no geometry keeps
  its inertia (a URDF's `<inertial>`), which is all the dynamics need.
- `<gazebo>`, `<transmission>` and other tags for other tools are left out.

`model` names the file: a path (relative to the YAML file's folder) or a `package://` URI.
"""

from __future__ import annotations

import os
import sys
import xml.etree.ElementTree as ElementTree
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import mujoco

from pbo_runtime import ROBOT_SUFFIXES

#: Mesh formats MuJoCo reads.
READABLE_MESHES = (".stl", ".obj", ".msh")
MAX_ROBOT_FILE_BYTES = 20 * 1024 * 1024  # a robot file is kilobytes; this refuses a runaway one early
_URDF_TAGS = {"link", "joint", "material"}  # what a URDF's <robot> holds for MuJoCo; the rest is for other tools


class RobotFileError(ValueError):
    """A robot that cannot be used; the message says what and how to fix it, `key` which plant key is
    at fault, `hint` (if any) what to write instead."""

    def __init__(self, message: str, key: str = "model", hint: str = "") -> None:
        super().__init__(message)
        self.key = key
        self.hint = hint


@dataclass
class RobotSource:
    """A robot file read: its spec (not compiled yet), where it came from, and what was changed."""

    path: Path
    spec: mujoco.MjSpec
    kind: str  # "urdf" or "mjcf"
    notes: list[str] = field(default_factory=list)
    velocity: dict[str, float] = field(default_factory=dict)  # joint name -> speed limit the file gives


def resolve(model: str, base_dir: Path) -> Path:
    """The file `model` names, from `base_dir` (the YAML file's folder); RobotFileError if there is none."""
    path = _package_path(model, base_dir) if model.startswith("package://") else (base_dir / os.path.expanduser(model)).resolve()
    if not path.is_file():
        raise RobotFileError(f"robot file {path} does not exist")
    if path.suffix.lower() not in ROBOT_SUFFIXES:
        raise RobotFileError(f"robot file {path.name} is not a URDF (.urdf) nor an MJCF (.xml)")
    return path


def read_robot(path: Path) -> RobotSource:
    """Read a URDF or an MJCF file into an MjSpec, making what MuJoCo cannot read loadable."""
    size = path.stat().st_size
    if size > MAX_ROBOT_FILE_BYTES:
        raise RobotFileError(f"robot file {path} is {size:,} bytes, more than the {MAX_ROBOT_FILE_BYTES:,} a robot file may be")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise RobotFileError(f"robot file {path} is not UTF-8 text (byte {exc.start})") from None
    if "<!ENTITY" in text or "<!DOCTYPE" in text:
        raise RobotFileError(f"robot file {path} declares entities or a DOCTYPE, which a robot file does not need; remove them")
    try:
        root = ElementTree.fromstring(text)
    except ElementTree.ParseError as exc:
        line, column = exc.position
        raise RobotFileError(f"robot file {path}:{line}:{column + 1} is not well-formed XML: {_parse_reason(exc)}") from None
    if root.tag == "robot":
        return _read_urdf(path, root)
    if root.tag == "mujoco":
        return _read_mjcf(path)
    raise RobotFileError(f"robot file {path} has a <{root.tag}> root; a URDF has <robot>, an MJCF <mujoco>")


def _parse_reason(exc: ElementTree.ParseError) -> str:
    return str(exc).split(":")[0]


def _read_urdf(path: Path, root: ElementTree.Element) -> RobotSource:
    notes: list[str] = []
    dropped = Counter[str]()
    for child in list(root):
        if child.tag not in _URDF_TAGS:
            root.remove(child)
            dropped[f"<{child.tag}>"] += 1
    if dropped:
        notes.append("left out, tags for other tools: " + ", ".join(f"{count} {tag}" for tag, count in sorted(dropped.items())))
    unreadable = Counter[str]()
    missing: list[str] = []
    bare: list[str] = []
    for link in root.iter("link"):
        for kind in ("visual", "collision"):
            for element in list(link.findall(kind)):
                mesh = element.find("geometry/mesh")
                if mesh is None:
                    continue
                try:
                    mesh_path = _mesh_path(mesh.get("filename", ""), path.parent)
                except RobotFileError as exc:
                    missing.append(str(exc))
                    link.remove(element)
                    continue
                if mesh_path.suffix.lower() not in READABLE_MESHES:
                    unreadable[f"{kind} {mesh_path.suffix.lower() or 'without a suffix'}"] += 1
                    link.remove(element)
                elif not mesh_path.is_file():
                    missing.append(f"mesh {mesh_path} does not exist")
                    link.remove(element)
                else:
                    mesh.set("filename", str(mesh_path))
        if link.find("collision") is None and link.find("visual") is None and link.find("inertial") is not None:
            bare.append(link.get("name", "?"))
    if unreadable:
        notes.append("dropped meshes MuJoCo cannot read (it reads STL, OBJ and MSH): "
                     + ", ".join(f"{count} {what}" for what, count in sorted(unreadable.items())))
    if missing:
        notes.append(f"dropped {len(missing)} mesh{'es' if len(missing) > 1 else ''} not found: {missing[0]}"
                     + (f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""))
    if bare:
        notes.append(f"kept as inertia only (no geometry left): {', '.join(bare)}")
    velocity = {}
    for joint in root.iter("joint"):
        limit = joint.find("limit")
        if limit is not None and limit.get("velocity") is not None:
            try:
                velocity[joint.get("name", "")] = abs(float(limit.get("velocity", "0")))
            except ValueError:
                raise RobotFileError(f"robot file {path}: joint {joint.get('name')!r} has a velocity limit that is not a number: "
                                     f"{limit.get('velocity')!r}") from None
    # MuJoCo's URDF reader: keep every link (fixed ones too, so an end effector link keeps its
    # name) and the mesh paths made absolute above.
    extension = ElementTree.SubElement(root, "mujoco")
    ElementTree.SubElement(extension, "compiler", strippath="false", fusestatic="false", discardvisual="false",
                           balanceinertia="true")
    root.remove(extension)
    root.insert(0, extension)
    try:
        spec = mujoco.MjSpec.from_string(ElementTree.tostring(root, encoding="unicode"))
    except ValueError as exc:
        raise RobotFileError(f"MuJoCo cannot read robot file {path}: {_mujoco_reason(exc)}") from None
    return RobotSource(path, spec, "urdf", notes, velocity)


def _read_mjcf(path: Path) -> RobotSource:
    try:
        spec = mujoco.MjSpec.from_file(str(path))
    except ValueError as exc:
        raise RobotFileError(f"MuJoCo cannot read robot file {path}: {_mujoco_reason(exc)}") from None
    notes: list[str] = []
    mesh_dir = Path(spec.modelfiledir or path.parent) / (spec.meshdir or "")
    dropped_meshes = set()
    for mesh in list(spec.meshes):
        if not mesh.file:
            continue
        mesh_path = Path(mesh.file) if Path(mesh.file).is_absolute() else mesh_dir / mesh.file
        if mesh_path.suffix.lower() not in READABLE_MESHES or not mesh_path.is_file():
            dropped_meshes.add(mesh.name)
    if dropped_meshes:
        for geom in list(spec.geoms):
            if geom.meshname in dropped_meshes:
                spec.delete(geom)
        for mesh in list(spec.meshes):
            if mesh.name in dropped_meshes:
                spec.delete(mesh)
        notes.append(f"dropped {len(dropped_meshes)} mesh{'es' if len(dropped_meshes) > 1 else ''} missing or in a "
                     f"format MuJoCo cannot read, and the geoms that used them: {', '.join(sorted(dropped_meshes)[:4])}"
                     + (" ..." if len(dropped_meshes) > 4 else ""))
    return RobotSource(path, spec, "mjcf", notes)


def _mujoco_reason(exc: ValueError) -> str:
    return " ".join(str(exc).replace("Error:", "").split())


def _mesh_path(filename: str, base_dir: Path) -> Path:
    if filename.startswith("package://"):
        return _package_path(filename, base_dir)
    if filename.startswith("file://"):
        return Path(filename[len("file://"):])
    return (base_dir / filename).resolve()


def _package_path(uri: str, start: Path) -> Path:
    """The file a `package://NAME/rest` URI names; RobotFileError naming where it looked."""
    name, _, rest = uri[len("package://"):].partition("/")
    if not name:
        raise RobotFileError(f"{uri!r} names no package")
    root = next(_package_roots(name, start), None)
    if root is not None:
        return (root / rest).resolve()
    raise RobotFileError(
        f"package {name!r} of {uri!r} is not in the file's folders nor in the search path; install the package "
        f"that ships it, or add the folder that holds {name}/ to PBO_ROBOT_PATH")


def _package_roots(name: str, start: Path) -> Iterator[Path]:
    """Candidate folders of package `name`, nearest first."""
    for folder in (start.resolve(), *start.resolve().parents):
        if folder.name == name or _package_xml_names(folder / "package.xml") == name:
            yield folder
    for entry in search_path():
        for candidate in (entry / name, entry / "share" / name):
            if candidate.is_dir():
                yield candidate


def search_path() -> list[Path]:
    """Where packages are looked for after the file's own tree, in order."""
    entries: list[Path] = []
    for variable in ("PBO_ROBOT_PATH", "ROS_PACKAGE_PATH", "AMENT_PREFIX_PATH"):
        entries += [Path(p) for p in os.environ.get(variable, "").split(os.pathsep) if p]
    entries += [Path(p) / "cmeel.prefix" for p in sys.path if p and Path(p, "cmeel.prefix").is_dir()]
    return entries


def _package_xml_names(path: Path) -> str | None:
    try:
        root = ElementTree.parse(path).getroot()
    except (OSError, ElementTree.ParseError):
        return None
    name = root.findtext("name")
    return name.strip() if name else None
