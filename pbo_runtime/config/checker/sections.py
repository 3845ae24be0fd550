"""The small top-level sections: the subsystem's name, dims, RTPUs, the bus and the plant."""

from __future__ import annotations

import dataclasses
import os
import re
from pathlib import Path
from typing import Any

from pbo_runtime.config.checker.base import CheckerBase, param_value_at
from pbo_runtime.config.checker.model import BUS_KEYS, RESTART_KEYS, RTPU_KEYS
from pbo_runtime.config.checker.words import describe, did_you_mean
from pbo_runtime.config.limits import MAX_DIM
from pbo_runtime.config.model import DEFAULT_SPIN, BusSpec, Location, PlantSpec, RestartPolicy, RtpuSpec
from pbo_runtime.config.root import leaves_root
from pbo_runtime.config.units import DATA_RATE, SIZE, TIME
from pbo_runtime.config.yaml_nodes import YList, YMap, location_of, plain
from pbo_runtime.errors import ModuleError, ParamError
from pbo_runtime.objects import registry
from pbo_runtime.objects.arm import ROBOT_OPTIONS, is_robot_file
from pbo_runtime.objects.module import convert_param, param_fields
from pbo_runtime.objects.ranges import OutOfRange

_SUBSYSTEM_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_-]*$")


class SectionChecks(CheckerBase):
    """Rules for `subsystem:`, `dims:`, `rtpus:`, `bus:` and `plant:`."""

    def check_subsystem(self, top: YMap) -> None:
        if "subsystem" not in top:
            return
        loc = top.value_loc("subsystem")
        name = self.text(top["subsystem"], loc, "'subsystem'")
        if name is None or not self.name_length(name, loc, "subsystem"):
            return
        if not _SUBSYSTEM_NAME.match(name):
            self.error(
                "E201",
                f"subsystem name {name!r} is not usable in shared-memory names",
                loc,
                "use letters, digits, '_' and '-', starting with a letter (e.g. puma)",
            )
            return
        self.out.name = name

    def check_dims(self, top: YMap) -> None:
        self.dims_node = top["dims"] if isinstance(top.get("dims"), YMap) else None
        for name, value, _, value_loc in self.entries(top, "dims", "dim", "e.g. dims: {NDOF: 6}"):
            size = self.integer(value, value_loc, f"dim '{name}'", minimum=1)
            if size is not None and size > MAX_DIM:
                self.error("E315", f"dim '{name}' must be at most {MAX_DIM:,}, got: {size:,}", value_loc,
                           "a dim counts joints, channels or pixels; is a digit too many?")
                size = None
            if size is not None:
                self.out.dims[name] = size
            else:
                self.bad_dims.add(name)  # reported here; a shape using it is not reported again

    def check_rtpus(self, top: YMap) -> None:
        if "rtpus" not in top:
            return
        value = top["rtpus"]
        loc = top.value_loc("rtpus")
        entries: list[tuple[Any, Location, Any, Location]] = []
        if isinstance(value, YList):
            entries = [(item, value.item_loc(i), None, value.item_loc(i)) for i, item in enumerate(value)]
        elif isinstance(value, YMap):
            entries = [(k, value.key_loc(k), v, value.value_loc(k)) for k, v in value.items()]
        else:
            self.error(
                "E113",
                f"'rtpus' must be a list of names or a mapping of name to {{cpu: N}}, got: {describe(value)}",
                loc,
                "e.g. rtpus: [rtpu0, rtpu1] or rtpus: {rtpu0: {cpu: 0}}",
            )
            return
        if not entries:
            self.error(
                "E119", "'rtpus' is empty: a subsystem needs at least one RTPU", location_of(value, loc), "e.g. rtpus: [rtpu0]"
            )
        everyone = self.restart_policy(top["restart"], top.value_loc("restart"), "the subsystem") if "restart" in top else None
        rtpus: list[RtpuSpec] = []
        for key, key_loc, spec, spec_loc in entries:
            name = self.name(key, key_loc, "RTPU")
            if name is None:
                continue
            if name in self.rtpu_names:
                self.error("E202", f"RTPU '{name}' is listed twice", key_loc)
                continue
            cpu = None
            restart = everyone
            spin, spin_loc = DEFAULT_SPIN, key_loc
            if spec is not None:
                m = self.mapping(spec, spec_loc, f"RTPU '{name}'", "e.g. rtpu0: {cpu: 0, spin: 200 us}")
                if m is not None:
                    self.keys(m, RTPU_KEYS, (), f"in RTPU '{name}'", key_loc)
                    if "cpu" in m and m["cpu"] is not None:
                        cpu = self.integer(m["cpu"], m.value_loc("cpu"), f"cpu of RTPU '{name}'", minimum=0)
                    if "spin" in m and m["spin"] is not None:
                        spin_loc = m.value_loc("spin")
                        given = self.quantity(m["spin"], spin_loc, TIME, f"spin of RTPU '{name}'", positive=False)
                        spin = DEFAULT_SPIN if given is None else given
                    if "restart" in m:
                        restart = self.restart_policy(m["restart"], m.value_loc("restart"), f"RTPU '{name}'")
            self.rtpu_names.add(name)
            rtpus.append(RtpuSpec(name, len(rtpus), cpu, key_loc, spin, spin_loc, restart))
        self.out.rtpus = tuple(rtpus)

    def restart_policy(self, value: Any, loc: Location, owner: str) -> RestartPolicy | None:
        """`{max: N, within: T}`: restart a dead RTPU at most N times within any T; `max: 0` never."""
        m = self.mapping(value, loc, f"restart of {owner}", "e.g. restart: {max: 3, within: 10 s}")
        if m is None:
            return None
        limit = self.integer(m["max"], m.value_loc("max"), f"max of the restart of {owner}", minimum=0) if "max" in m else None
        # only max is always required; within counts the deaths of max > 0: said missing only when
        # max is a count > 0 and no unknown key is there (a key unlike 'within' is said unknown, with
        # the valid keys; one like it, as a misspelt within)
        unknown = [str(k) for k in m if k not in RESTART_KEYS]
        like_within = any(did_you_mean(key, ("within",)).startswith("did you mean") for key in unknown)
        wants_within = isinstance(limit, int) and limit > 0 and (not unknown or like_within)
        required = ("max", "within") if wants_within else ("max",)
        self.keys(m, RESTART_KEYS, required, f"in the restart of {owner}", loc)
        within = None
        if "within" in m:
            within = self.quantity(m["within"], m.value_loc("within"), TIME, f"within of the restart of {owner}")
        if limit == 0:
            return None  # never restarted: its death stops the run, as with no policy
        if limit is None or within is None:
            return None
        return RestartPolicy(limit, within, location_of(value, loc))

    def check_bus(self, top: YMap) -> None:
        bus = self.section(top, "bus", "e.g. bus: {bandwidth: 40 MB/s, lock_overhead: 16 B}")
        if bus is None:
            return
        self.keys(bus, BUS_KEYS, (), "in 'bus'", top.key_loc("bus"))
        defaults = BusSpec()
        bandwidth: float | None = defaults.bandwidth
        overhead: float | None = defaults.lock_overhead
        if "bandwidth" in bus:
            bandwidth = self.quantity(bus["bandwidth"], bus.value_loc("bandwidth"), DATA_RATE, "bus bandwidth")
        if "lock_overhead" in bus:
            overhead = self.quantity(
                bus["lock_overhead"], bus.value_loc("lock_overhead"), SIZE, "bus lock_overhead", positive=False
            )
        if bandwidth is not None and overhead is not None:
            self.out.bus = BusSpec(bandwidth, overhead, bus.loc)

    def check_plant(self, top: YMap) -> None:
        self.plant_written = "plant" in top and top["plant"] is not None
        plant = self.section(top, "plant", "e.g. plant: {model: puma560, timestep: 1 ms}")
        if plant is None:
            return
        defaults = PlantSpec()
        kind: str | None = defaults.type
        model: str | None = defaults.model
        timestep: float | None = defaults.timestep
        if "type" in plant:
            kind = self.text(plant["type"], plant.value_loc("type"), "plant type")
        if "model" in plant:
            model = self.text(plant["model"], plant.value_loc("model"), "plant model")
        if "timestep" in plant:
            timestep = self.quantity(plant["timestep"], plant.value_loc("timestep"), TIME, "plant timestep")
        options = {k: plain(v) for k, v in plant.items() if k not in ("type", "model", "timestep")}
        for key in options:
            if not isinstance(key, str):
                self.error("E118", f"plant option names must be text, got: {describe(key)}", plant.key_loc(key))
        if kind is not None and model is not None and timestep is not None:
            self.out.plant = PlantSpec(kind, model, timestep, options, plant.loc)
            wrong = self.check_plant_options(plant, self.out.plant)
            # the robot is still described (its NDOF is a dim), without the options already refused
            robot = dataclasses.replace(self.out.plant, options={k: v for k, v in options.items() if k not in wrong})
            self.check_robot(plant, robot)

    def check_plant_options(self, plant: YMap, spec: PlantSpec) -> set[Any]:
        """The plant's options against what its type declares (`Options`, a dataclass like a module's
        Params): names (E111, with a did-you-mean), types and lengths (E320), each at its own key;
        then the plant's own check of them together. The options refused (none when nothing is declared)."""
        try:
            declared = getattr(registry.plant_class(spec.type), "Options", None)
        except ModuleError:
            return set()  # an unregistered plant type is refused when the run starts
        if not (isinstance(declared, type) and dataclasses.is_dataclass(declared)):
            return set()
        fields = param_fields(declared)
        owner = f"plant {spec.type}"
        wrong: set[Any] = set()
        values: dict[str, Any] = {}
        for key, value in spec.options.items():
            if not isinstance(key, str):
                wrong.add(key)  # reported above (E118)
                continue
            if key not in fields:
                self.error("E111", f"unknown option '{key}' of {owner}", plant.key_loc(key),
                           did_you_mean(key, [*fields, "type", "model", "timestep"], "options"))
                wrong.add(key)
                continue
            loc = plant.value_loc(key)
            try:
                values[key] = convert_param(declared, key, value, f"plant option {key}")
            except OutOfRange as exc:  # at the very number, an element of a list too
                self.error("E320", str(exc), param_value_at(plant, key, exc.index) or location_of(plant[key], loc))
                wrong.add(key)
                continue
            except ParamError as exc:
                self.error("E320", str(exc), location_of(plant[key], loc))
                wrong.add(key)
                continue
            problem = self._option_length(key, values[key], fields[key].metadata.get("shape"), spec)
            if problem:
                self.error(
                    "E320",
                    problem,
                    location_of(plant[key], loc),
                    "give one value per joint, or leave the option out for the robot's own"
                    if fields[key].metadata.get("shape") == ("NDOF",)
                    else "",
                )
                wrong.add(key)
        if wrong:
            return wrong
        try:
            declared(**values)
        except (TypeError, ValueError) as exc:
            named = next((k for k in values if re.search(rf"\b{re.escape(k)}\b", str(exc))), None)
            self.error("E320", str(exc), plant.value_loc(named) if named is not None else plant.loc)
            return {named} if named is not None else set(values)
        return set()

    def _option_length(self, key: str, value: Any, shape: Any, spec: PlantSpec) -> str:
        """'' if a list option has the length its declared shape says; else what is wrong. A dim
        (NDOF) is the robot's when it is known without loading it, else the file's dims:."""
        if not isinstance(value, tuple) or not isinstance(shape, tuple) or len(shape) != 1:
            return ""
        size, named = shape[0], ""
        if isinstance(size, str):
            robot = self._plant_robot_dims() if not is_robot_file(spec.model) else {}
            dim = size
            size = robot.get(dim, self.out.dims.get(dim))
            if size is None:
                return ""  # a robot file's joints are known once it is loaded: checked then
            named = f" ({dim}: the joints of {spec.model})" if dim in robot else f" ({dim})"
        if len(value) == size:
            return ""
        return f"plant option {key} must have {size} values{named}, got: {len(value)}"

    def check_robot(self, plant: YMap, spec: PlantSpec) -> None:
        """The plant's robot: a registered one, or a file that loads, with its end effector; its NDOF.

        A registered robot without robot options is known by its dims alone (no simulator is loaded);
        a robot file, or robot options, are checked by the plant itself, as it will load them.
        """
        model_loc = plant.value_loc("model") if "model" in plant else plant.loc
        robot_options = sorted(set(spec.options) & set(ROBOT_OPTIONS))
        if not is_robot_file(spec.model) and spec.model not in registry.names(registry.ROBOTS):
            if not self._plant_describes_robots(spec.type):
                return  # a plant of another kind: its model is its own, checked when it starts
            self.error("E216", f"plant model {spec.model!r} is neither a registered robot nor a robot file", model_loc,
                       did_you_mean(spec.model, registry.names(registry.ROBOTS), "registered")
                       + "; or give a URDF (.urdf) or MJCF (.xml) file, relative to this file")
            return
        described = {} if is_robot_file(spec.model) or robot_options else self._plant_robot_dims()
        if described:  # a registered DH robot: its dims (and limits) are known without loading a simulator
            self._robot_dims = described
            self._robot_limits(registry.registered_robot(spec.model))
        else:
            try:
                describe = registry.plant_class(spec.type).describe_robot
            except (ModuleError, AttributeError):
                return  # a plant of another kind checks its own options when it starts
            base_dir = Path(spec.loc.file).resolve().parent if spec.loc.file else Path.cwd()
            root = robot_file_outside_root(spec.model, base_dir)
            if root is not None:
                self.error("E107", f"robot file {spec.model!r} is outside {root}, the folder this server reads", model_loc,
                           "the local API reads the subsystem file's folder and below only; move the robot file into it")
                return
            options = dict(spec.options)
            while True:
                try:
                    robot = describe(spec.model, str(base_dir), options)
                    break
                except ValueError as exc:
                    key = getattr(exc, "key", "model")
                    loc = plant.value_loc(key) if key in plant else model_loc
                    self.error("E217" if key == "ee" else "E216", str(exc), loc, getattr(exc, "hint", ""))
                    if key not in options:
                        return  # the robot itself cannot be loaded
                    # a robot option it refuses (reported): the robot without it still gives its dims (NDOF)
                    del options[key]
            self._robot_dims = dict(robot.dims)
            name = Path(robot.source).name
            self.out.robot_notes = [f"robot {name}: {robot.ndof} joints ({', '.join(robot.joint_names)}), "
                                    f"end effector {robot.ee_name}"]
            self.out.robot_notes += [f"robot {name}: {note}" for note in robot.notes]
            self._robot_limits(robot)
        self._check_robot_ndof(plant)

    def _robot_limits(self, robot: Any) -> None:
        """The joints' limits the robot gives (`limit_rows`: the robot's, tightened by the plant options), for the output."""
        self.described_robot = robot  # the joint loops' check reads its arm
        rows = getattr(robot, "limit_rows", None)
        if callable(rows):
            self.out.robot_limits = list(rows())

    @staticmethod
    def _plant_describes_robots(kind: str) -> bool:
        """Whether plants of type `kind` simulate robots (`describe_robot`); False for a type that is
        not registered (the plant host refuses it when the run starts)."""
        try:
            return hasattr(registry.plant_class(kind), "describe_robot")
        except ModuleError:
            return False

    def _check_robot_ndof(self, plant: YMap) -> None:
        """NDOF in `dims:` must be the robot's joint count: say both places."""
        given = self.out.dims.get("NDOF")
        robot = (self._robot_dims or {}).get("NDOF")
        if given is None or robot is None or given == robot or self.dims_node is None:
            return
        model = plant.get("model", PlantSpec().model)
        where = plant.value_loc("model") if "model" in plant else plant.loc
        self.error("E318", f"dim 'NDOF' is {given} here, but the plant's robot {model!r} has {robot} joints "
                           f"(at {where.file}:{where.line}:{where.column})",
                   self.dims_node.value_loc("NDOF"),
                   f"remove NDOF from dims: (the robot gives it) or set it to {robot}")


def robot_file_outside_root(model: str, base_dir: Path) -> str | None:
    """The root (`config.root`) a plant's robot file leaves, or None. A `package://` URI is looked for
    in the installed robot packages, so only one that climbs out with `..` is refused."""
    if model.startswith("package://"):
        return leaves_root("/") if ".." in Path(model[len("package://"):]).parts else None
    return leaves_root(base_dir / os.path.expanduser(model))
