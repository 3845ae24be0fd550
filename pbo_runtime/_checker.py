"""The configuration checker: every rule of DESIGN.md §6 and §12, all errors of a file in one pass.

It walks a loaded YAML document (`_yaml_nodes.YMap`), reports each mistake like a compiler
(`file:line:col: error[E403]: ...` with the objects, what was found, the valid choices and a hint;
every rule has a stable code, listed in docs/error-codes.md),
and builds the frozen specs of `_config_model` from what is right, so the loader can assemble a
`Subsystem` when nothing is wrong. It never stops at the first mistake: a broken part is left out
of the later rules so one typo does not cascade into a page of follow-on errors.
"""

from __future__ import annotations

import difflib
import functools
import graphlib
import heapq
import re
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from pbo_runtime._config_model import (
    NOWHERE,
    ApplicationSpec,
    ApplicationStep,
    BusSpec,
    ConfigurationSpec,
    DEFAULT_SPIN,
    DeviceSpec,
    JobSpec,
    Location,
    PlantSpec,
    PortBinding,
    PortClaim,
    RtpuSpec,
    TaskSpec,
    VariableSpec,
)
from pbo_runtime import _registry
from pbo_runtime._channels import EXAMPLE as CHANNELS_EXAMPLE
from pbo_runtime._channels import ChannelError, format_channels, parse_channels
from pbo_runtime._errors import ConfigError, ParamError
from pbo_runtime._expressions import ALLOWED, ExpressionError, compile_condition
from pbo_runtime._ports import ANY_DTYPE, PortSpec
from pbo_runtime._units import DATA_RATE, FREQUENCY, SIZE, TIME, parse_quantity
from pbo_runtime._yaml_nodes import YList, YMap, location_of, plain

DTYPES = ("float64", "float32", "int64", "int32", "int16", "int8", "uint64", "uint32", "uint16", "uint8", "bool")  # what the table holds

TOP_KEYS = (
    "subsystem",
    "include",
    "rtpus",
    "bus",
    "plant",
    "devices",
    "dims",
    "variables",
    "tasks",
    "configurations",
    "jobs",
    "applications",
)
TOP_REQUIRED = ("subsystem", "rtpus", "variables", "tasks", "configurations")
VARIABLE_KEYS = ("type", "shape", "doc", "object", "initial")
TASK_KEYS = (
    "module", "rtpu", "period", "rate", "aperiodic", "min_interarrival", "wcet",
    "priority", "critical", "params", "ports", "resources",
)
JOB_KEYS = ("configuration", "object", "pre", "post", "timeout")
DEVICE_KEYS = ("driver", "exclusive", "io")  # every other key of a device is a driver option
CLAIM_KEYS = ("device", "channels")  # a resource or an io: given as {device: adc0, channels: 0-5}
BUS_KEYS = ("bandwidth", "lock_overhead")
RTPU_KEYS = ("cpu", "spin")

_SUBSYSTEM_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_-]*$")
_JOIN_HINT = "an output has one writer; join them with a join connector (TR Figure 6)"

ModuleLookup = Callable[[str], Any]
DriverLookup = Callable[[str], Any]


@dataclass
class Checked:
    """What the checker found: the problems, and the specs built from the parts that are right."""

    errors: list[ConfigError] = field(default_factory=list)
    warnings: list[ConfigError] = field(default_factory=list)
    name: str = ""
    rtpus: tuple[RtpuSpec, ...] = ()
    bus: BusSpec = field(default_factory=BusSpec)
    plant: PlantSpec | None = None
    devices: dict[str, DeviceSpec] = field(default_factory=dict)
    dims: dict[str, int] = field(default_factory=dict)
    variables: dict[str, VariableSpec] = field(default_factory=dict)
    initial_values: dict[str, np.ndarray] = field(default_factory=dict)
    tasks: dict[str, TaskSpec] = field(default_factory=dict)
    configurations: dict[str, ConfigurationSpec] = field(default_factory=dict)
    jobs: dict[str, JobSpec] = field(default_factory=dict)
    applications: dict[str, ApplicationSpec] = field(default_factory=dict)
    init_order: tuple[str, ...] = ()


@dataclass
class _Binding:
    """A port of a task linked to a variable, with where the link was written."""

    port: PortSpec
    variable: str
    shape: tuple[int, ...]
    loc: Location


@dataclass
class _Task:
    """A task as far as it could be resolved; `ok` is False when its ports are unknown."""

    name: str
    index: int
    loc: Location
    module: str = ""
    ok: bool = False
    bindings: list[_Binding] = field(default_factory=list)
    resources: list[tuple[str, Location]] = field(default_factory=list)
    channels: dict[str, tuple[int, ...]] = field(default_factory=dict)  # device -> channels, where a subset is given
    rtpu: str = ""
    period: float = 0.0
    priority: int = 0
    critical: bool = False
    wcet: float | None = None
    aperiodic: bool = False
    min_interarrival: float | None = None
    params: dict[str, Any] = field(default_factory=dict)
    built_params: Any = None  # the module's Params instance, once the params checked out


@functools.cache
def _dtype_name(raw: str) -> str:
    """numpy's canonical name of a dtype (working it out costs microseconds: once per name)."""
    return str(np.dtype(raw))


LISTED = 12  # choices named in a hint; a longer list helps nobody read it


def did_you_mean(name: object, choices: Iterable[str], what: str = "valid") -> str:
    """'did you mean 'x'? (valid: a, b, c)' - the hint for an unknown name."""
    options = sorted({str(c) for c in choices})
    text = str(name)
    # A truncation ('prio' for 'priority') is the likeliest slip; difflib alone may prefer 'period'.
    close = [o for o in options if len(text) >= 3 and o.startswith(text)][:1]
    close = close or difflib.get_close_matches(text, options, n=1, cutoff=0.6)
    shown = options if len(options) <= LISTED else [*options[:LISTED], f"... {len(options) - LISTED} more"]
    listing = f"({what}: {', '.join(shown)})" if options else f"({what}: none)"
    if close:
        return f"did you mean '{close[0]}'? {listing}"
    return listing


def describe(value: object) -> str:
    """A short, plain description of a YAML value for 'got: ...'."""
    if value is None:
        return "nothing (null)"
    if isinstance(value, bool):
        return f"true/false ({str(value).lower()})"
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, str):
        return f"the text {value!r}"
    if isinstance(value, int):
        return f"the integer {value}"
    if isinstance(value, float):
        return f"the number {value}"
    return f"{type(value).__name__} {value!r}"


def _ms(seconds: float) -> str:
    """A time as an engineer writes it: '1 ms', '0.25 ms', '2 s'."""
    if seconds >= 1:
        return f"{seconds:g} s"
    return f"{seconds * 1e3:g} ms"


def _show_shape(shape: Sequence[object]) -> str:
    if not shape:
        return "() (a scalar)"
    return "(" + ", ".join(str(d) for d in shape) + ("," if len(shape) == 1 else "") + ")"


def _and_list(items: Sequence[str]) -> str:
    """'a', 'a and b', 'a, b and c'."""
    if len(items) <= 1:
        return "".join(items)
    return ", ".join(items[:-1]) + " and " + items[-1]


@dataclass(frozen=True)
class _Claim:
    """Channels of a device a task takes when it opens a resource: directly, or `via` a sensor wired to it."""

    task: str
    device: str
    channels: tuple[int, ...] | None  # None: no channel is locked (a device that is not port-based)
    loc: Location
    via: str | None = None  # the sensor-actuator device whose io: brought this claim

    def who(self) -> str:
        through = f", through device '{self.via}'" if self.via else ""
        return f"'{self.task}' (line {self.loc.line}{through})"


class _Checker:
    def __init__(self, file: str, module_lookup: ModuleLookup, module_names: Callable[[], Iterable[str]] | None,
                 driver_lookup: DriverLookup | None = None) -> None:
        self.file = file
        self.module_lookup = module_lookup
        self.module_names = module_names
        self.driver_lookup = driver_lookup or _registry.driver_class
        self._drivers: dict[str, Any] = {}
        self._claims: dict[str, list[_Claim]] = {}
        self.out = Checked()
        self.rtpu_names: set[str] = set()
        self.var_initial: set[str] = set()
        self.var_object: dict[str, str] = {}
        self.var_locs: dict[str, Location] = {}
        self.var_ok: set[str] = set()
        self.tasks: dict[str, _Task] = {}
        self.task_names: set[str] = set()
        self.config_names: set[str] = set()
        self.config_members: dict[str, list[tuple[str, Location]]] = {}
        self.config_repeats: dict[str, set[str]] = {}  # tasks flagged E407 (a module repeated), per configuration
        self.config_locs: dict[str, Location] = {}
        self.job_names: set[str] = set()
        self.expression_names: set[str] = set()
        self.device_names: set[str] = set()
        self.sources: dict[str, list[str]] = {}
        self.app_names: set[str] = set()
        self._port_shapes: dict[Any, tuple[int, ...]] = {}  # a port's declared shape -> resolved with the dims

    # --- reporting --------------------------------------------------------------------------

    def error(self, code: str, message: str, loc: Location, hint: str = "") -> None:
        self.out.errors.append(ConfigError(message, loc.file, loc.line, loc.column, hint, code=code))

    def warn(self, code: str, message: str, loc: Location, hint: str = "") -> None:
        self.out.warnings.append(ConfigError(message, loc.file, loc.line, loc.column, hint, severity="warning", code=code))

    # --- shape helpers ----------------------------------------------------------------------

    def mapping(self, value: Any, loc: Location, what: str, example: str = "") -> YMap | None:
        """The value if it is a mapping, else an error saying what was expected."""
        if isinstance(value, YMap):
            return value
        self.error("E113", f"{what} must be a mapping, got: {describe(value)}", location_of(value, loc), example)
        return None

    def keys(self, m: YMap, allowed: Sequence[str], required: Sequence[str], where: str, owner_loc: Location) -> None:
        missing = [key for key in required if key not in m]
        for key in m:
            if key not in allowed:
                close = difflib.get_close_matches(str(key), missing, n=1, cutoff=0.6)
                if close:  # one mistake, one error: a misspelt required key
                    missing.remove(close[0])
                    self.error("E111", f"unknown key '{key}' {where}: did you mean the required key '{close[0]}'?", m.key_loc(key),
                               f"rename it '{close[0]}:'")
                else:
                    self.error("E111", f"unknown key '{key}' {where}", m.key_loc(key), did_you_mean(key, allowed))
        if not missing:
            return
        subject = where[3:] if where.startswith("in ") else "the file" if where == "at the top level" else where
        for key in missing:
            self.error("E112", f"{subject} has no '{key}:', which is required", owner_loc, f"add '{key}:' (keys: {', '.join(allowed)})")

    def name(self, key: object, loc: Location, what: str) -> str | None:
        if isinstance(key, str) and key:
            return key
        self.error("E118", f"{what} names must be text, got: {describe(key)}", loc, "write the name as plain text, e.g. q_m")
        return None

    def text(self, value: Any, loc: Location, what: str) -> str | None:
        if isinstance(value, str):
            return value
        self.error("E114", f"{what} must be text, got: {describe(value)}", location_of(value, loc))
        return None

    def boolean(self, value: Any, loc: Location, what: str) -> bool | None:
        if isinstance(value, bool):
            return value
        self.error("E115", f"{what} must be true or false, got: {describe(value)}", location_of(value, loc))
        return None

    def integer(self, value: Any, loc: Location, what: str, minimum: int | None = None) -> int | None:
        if not isinstance(value, int) or isinstance(value, bool):
            self.error("E116", f"{what} must be an integer, got: {describe(value)}", location_of(value, loc))
            return None
        if minimum is not None and value < minimum:
            self.error("E117", f"{what} must be >= {minimum}, got: {value}", loc)
            return None
        return value

    def quantity(self, value: Any, loc: Location, kind: str, what: str, positive: bool = True) -> float | None:
        try:
            number = parse_quantity(value, kind)
        except ValueError as exc:
            hint = ""
            if kind == TIME and "that is a frequency" in str(exc):
                hint = "give a rate as 'rate: 1 kHz', or a period as 'period: 1 ms'"
            self.error("E501", f"{what}: {exc}", location_of(value, loc), hint)
            return None
        if positive and number <= 0:
            self.error("E502", f"{what} must be > 0, got: {value}", loc)
            return None
        if not positive and number < 0:
            self.error("E502", f"{what} must be >= 0, got: {value}", loc)
            return None
        return number

    # --- the pass ---------------------------------------------------------------------------

    def run(self, doc: Any, doc_loc: Location) -> Checked:
        if doc is None:
            self.error(
                "E110",
                "the file is empty",
                doc_loc,
                "a subsystem file is a mapping with keys " + ", ".join(TOP_REQUIRED),
            )
            return self.out
        top = self.mapping(doc, doc_loc, "the top level", "a subsystem file is a mapping with keys " + ", ".join(TOP_REQUIRED))
        if top is None:
            return self.out
        self.keys(top, TOP_KEYS, TOP_REQUIRED, "at the top level", top.loc)
        self.check_subsystem(top)
        self.check_dims(top)
        self.check_rtpus(top)
        self.check_bus(top)
        self.check_plant(top)
        self.check_devices(top)
        self.check_variables(top)
        self.check_tasks(top)
        self.check_configurations(top)
        self.check_jobs(top)
        self.check_applications(top)
        for config in self.config_members:
            self.check_data_flow(config)
        self.check_device_union()
        self.check_schedulability()
        self.check_spins()
        self.check_const_order()
        self.check_unused()
        return self.out

    def section(self, top: YMap, key: str, example: str) -> YMap | None:
        """A top-level section that maps names to entries; None (and an error) if it is not one."""
        if key not in top or top[key] is None:
            return None
        return self.mapping(top[key], top.value_loc(key), f"'{key}'", example)

    def check_subsystem(self, top: YMap) -> None:
        if "subsystem" not in top:
            return
        loc = top.value_loc("subsystem")
        name = self.text(top["subsystem"], loc, "'subsystem'")
        if name is None:
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
        dims = self.section(top, "dims", "e.g. dims: {NDOF: 6}")
        if dims is None:
            return
        for key, value in dims.items():
            name = self.name(key, dims.key_loc(key), "dim")
            if name is None:
                continue
            size = self.integer(value, dims.value_loc(key), f"dim '{name}'", minimum=1)
            if size is not None:
                self.out.dims[name] = size

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
            self.error("E119", "'rtpus' is empty: a subsystem needs at least one RTPU", location_of(value, loc), "e.g. rtpus: [rtpu0]")
        rtpus: list[RtpuSpec] = []
        for key, key_loc, spec, spec_loc in entries:
            name = self.name(key, key_loc, "RTPU")
            if name is None:
                continue
            if name in self.rtpu_names:
                self.error("E202", f"RTPU '{name}' is listed twice", key_loc)
                continue
            cpu = None
            spin, spin_loc = DEFAULT_SPIN, key_loc
            if spec is not None:
                m = self.mapping(spec, spec_loc, f"RTPU '{name}'", "e.g. rtpu0: {cpu: 0, spin: 200 us}")
                if m is not None:
                    self.keys(m, RTPU_KEYS, (), f"in RTPU '{name}'", key_loc)
                    if "cpu" in m and m["cpu"] is not None:
                        cpu = self.integer(m["cpu"], m.value_loc("cpu"), f"cpu of RTPU '{name}'", minimum=0)
                    if "spin" in m and m["spin"] is not None:
                        spin_loc = m.value_loc("spin")
                        spin = self.quantity(m["spin"], spin_loc, TIME, f"spin of RTPU '{name}'", positive=False)
                        if spin is None:
                            spin = DEFAULT_SPIN
            self.rtpu_names.add(name)
            rtpus.append(RtpuSpec(name, len(rtpus), cpu, key_loc, spin, spin_loc))
        self.out.rtpus = tuple(rtpus)

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
            overhead = self.quantity(bus["lock_overhead"], bus.value_loc("lock_overhead"), SIZE, "bus lock_overhead", positive=False)
        if bandwidth is not None and overhead is not None:
            self.out.bus = BusSpec(bandwidth, overhead, bus.loc)

    def check_plant(self, top: YMap) -> None:
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

    def check_devices(self, top: YMap) -> None:
        devices = self.section(top, "devices", "e.g. devices: {arm: {driver: mujoco_arm, exclusive: true}}")
        if devices is None:
            return
        for key, value in devices.items():
            key_loc = devices.key_loc(key)
            name = self.name(key, key_loc, "device")
            if name is None:
                continue
            self.device_names.add(name)
            spec = self.mapping(value, devices.value_loc(key), f"device '{name}'", "e.g. arm: {driver: mujoco_arm, exclusive: true}")
            if spec is None:
                continue
            if "driver" not in spec:
                self.error("E112", f"device '{name}' has no 'driver:', which is required", key_loc, "add 'driver: <name>' (a registered driver)")
                continue
            driver = self.text(spec["driver"], spec.value_loc("driver"), f"driver of device '{name}'")
            exclusive: bool | None = False
            if "exclusive" in spec:
                exclusive = self.boolean(spec["exclusive"], spec.value_loc("exclusive"), f"'exclusive' of device '{name}'")
            io: PortClaim | None = None
            io_ok = True
            if "io" in spec:
                io = self.port_claim(spec["io"], spec.value_loc("io"), f"io of device '{name}'", f"device '{name}' (io:)", allow_name=False)
                io_ok = io is not None
            options = {k: plain(v) for k, v in spec.items() if k not in DEVICE_KEYS}
            bad = [k for k in options if not isinstance(k, str)]
            for k in bad:
                self.error("E118", f"option names of device '{name}' must be text, got: {describe(k)}", spec.key_loc(k))
            if driver is not None and not bad and not self.driver_accepts(name, driver, options, key_loc):
                continue
            if driver is not None and exclusive is not None and not bad and io_ok:
                self.out.devices[name] = DeviceSpec(name, driver, exclusive, options, key_loc, io)
        self.check_device_wiring()

    # --- devices: drivers, channels, wiring -------------------------------------------------

    def driver_class(self, driver: str) -> Any:
        """The registered driver class, or None when it cannot be found (then only the YAML is checked)."""
        if driver not in self._drivers:
            try:
                found = self.driver_lookup(driver)
            except Exception:  # an unknown driver fails when the device is opened; the checker checks what it can
                found = None
            self._drivers[driver] = found if isinstance(found, type) else None
        return self._drivers[driver]

    def ports_of(self, device: str) -> int | None:
        """How many channels a device has (0: not port-based), or None when its driver is unknown."""
        spec = self.out.devices.get(device)
        cls = self.driver_class(spec.driver) if spec is not None else None
        if cls is None:
            return None
        ports = getattr(cls, "PORTS", 0)
        return ports if isinstance(ports, int) and ports >= 0 else 0

    def driver_accepts(self, name: str, driver: str, options: dict[str, Any], loc: Location) -> bool:
        """The driver's own check of the device's options (E607); True when it has none or they pass."""
        cls = self.driver_class(driver)
        check = getattr(cls, "check_options", None)
        if check is None:
            return True
        try:
            check(options)
        except (ValueError, TypeError) as exc:
            self.error("E607", f"device '{name}' (driver {driver}): {exc}", loc,
                       "the driver's docstring lists its options (docs/modules.md, 'Drivers')")
            return False
        return True

    def port_claim(self, value: Any, loc: Location, what: str, owner: str, allow_name: bool) -> PortClaim | None:
        """A device name (if `allow_name`) or {device: name, channels: ...}, as a PortClaim; None (and errors) if wrong."""
        if allow_name and isinstance(value, str):
            return PortClaim(value, None, loc)
        example = "e.g. {device: adc0, channels: 0-5}"
        if not isinstance(value, YMap):
            expected = "a device name or a mapping {device: ..., channels: ...}" if allow_name else "a mapping {device: ..., channels: ...}"
            self.error("E113", f"{what} must be {expected}, got: {describe(value)}", location_of(value, loc), example)
            return None
        self.keys(value, CLAIM_KEYS, ("device",), f"in {what}", loc)
        if "device" not in value:
            return None
        device = self.text(value["device"], value.value_loc("device"), f"device of {what}")
        if device is None:
            return None
        channels: tuple[int, ...] | None = None
        if "channels" in value:
            channels_loc = value.value_loc("channels")
            try:
                channels = parse_channels(plain(value["channels"]))
            except ChannelError as exc:
                self.error("E604", f"{owner}: channels of device '{device}': {exc}", location_of(value["channels"], channels_loc),
                           CHANNELS_EXAMPLE)
                return None
        if any(k not in CLAIM_KEYS for k in value):
            return None
        return PortClaim(device, channels, value.value_loc("device"))

    def channels_exist(self, claim: PortClaim, what: str) -> bool:
        """E605 unless the claimed channels are channels of the device (when its driver is known)."""
        if claim.channels is None:
            return True
        ports = self.ports_of(claim.device)
        if ports is None:
            return True
        driver = self.out.devices[claim.device].driver
        if ports == 0:
            self.error("E605", f"{what} opens channels {format_channels(claim.channels)} of device '{claim.device}', "
                       f"but its driver {driver} is not a port-based I/O device: it has no channels", claim.loc,
                       f"open it whole: write just '{claim.device}'")
            return False
        missing = [c for c in claim.channels if c >= ports]
        if missing:
            self.error("E605", f"{what} opens channel(s) {format_channels(missing)} of device '{claim.device}', "
                       f"which has channels 0-{ports - 1} (driver {driver})", claim.loc,
                       f"choose channels among 0-{ports - 1}")
            return False
        return True

    def check_device_wiring(self) -> None:
        """Each device's io: names a declared I/O device of the kind its driver reads, with channels it has (E605, E606)."""
        for name, spec in list(self.out.devices.items()):
            cls = self.driver_class(spec.driver)
            wants = getattr(cls, "IO", "") if cls is not None else None
            claim = spec.io
            if claim is None:
                if wants:
                    self.error("E606", f"device '{name}' (driver {spec.driver}) reads through a device of kind {wants}, but it has no io:",
                               spec.loc, f"say where it is wired, e.g. io: {{device: <a device of kind {wants}>, channels: 0-5}}")
                    del self.out.devices[name]
                continue
            where = f"device '{name}'"
            problem = ""
            hint = ""
            if claim.device not in self.device_names:
                problem = f"{where} is wired (io:) to device '{claim.device}', which 'devices' does not declare"
                hint = did_you_mean(claim.device, self.device_names, "declared")
            elif claim.device == name or self._wired_through(claim.device, name):
                problem = f"{where} is wired (io:) to itself through {claim.device}"
                hint = "io: names the I/O device (adc, dac, parallel port) the sensor's cable goes to"
            elif wants == "":
                problem = f"{where}: driver {spec.driver} reads no I/O device, so it takes no io:"
                hint = "remove io:, or choose a sensor-actuator driver that reads through an I/O device"
            elif claim.device in self.out.devices and wants:
                io_driver = self.out.devices[claim.device].driver
                io_cls = self.driver_class(io_driver)
                kind = getattr(io_cls, "KIND", "") if io_cls is not None else None
                if kind is not None and kind != wants:
                    found = f"is of kind {kind}" if kind else "is not an I/O device"
                    problem = (f"{where} (driver {spec.driver}) reads through a device of kind {wants}, but its io: "
                               f"device '{claim.device}' {found} (driver {io_driver})")
                    hint = f"wire it to a device of kind {wants}"
            if problem:
                self.error("E606", problem, claim.loc, hint)
                del self.out.devices[name]
                continue
            if claim.device not in self.out.devices:
                continue  # the I/O device itself is wrong, and was reported there
            if not self.channels_exist(claim, where):
                del self.out.devices[name]
                continue
            needs = getattr(cls, "IO_CHANNELS", 0) if cls is not None else 0
            ports = self.ports_of(claim.device)
            count = len(claim.channels) if claim.channels is not None else ports
            if needs and count is not None and count != needs:
                shown = format_channels(claim.channels) if claim.channels is not None else "all of them"
                self.error("E605", f"{where} (driver {spec.driver}) needs {needs} channels of its {wants} device, "
                           f"but io: gives {count} ({shown})", claim.loc,
                           f"give exactly {needs} channels, e.g. channels: 0-{needs - 1}")
                del self.out.devices[name]

    def _wired_through(self, device: str, target: str) -> bool:
        """True if following io: from `device` reaches `target` (a wiring loop)."""
        seen: set[str] = set()
        while device not in seen:
            seen.add(device)
            spec = self.out.devices.get(device)
            if spec is None or spec.io is None:
                return False
            device = spec.io.device
            if device == target:
                return True
        return False

    # --- variables --------------------------------------------------------------------------

    def resolve_shape(self, value: Any, loc: Location, owner: str) -> tuple[int, ...] | None:
        if isinstance(value, YList):
            items: list[Any] = value
            where = value.item_loc  # locations are worked out only for an error
        elif (isinstance(value, int) and not isinstance(value, bool)) or isinstance(value, str):
            items = [value]  # 'shape: 6' and 'shape: NDOF' mean one dimension
            where = lambda _index: loc  # noqa: E731
        else:
            self.error(
                "E113",
                f"shape of {owner} must be a list of sizes or dim names, got: {describe(value)}",
                location_of(value, loc),
                "e.g. shape: [NDOF, 4]; leave shape out for a scalar",
            )
            return None
        shape: list[int] = []
        ok = True
        dims = self.out.dims
        for index, item in enumerate(items):
            if isinstance(item, str):
                if item in dims:
                    shape.append(dims[item])
                else:
                    self.error(
                        "E204",
                        f"shape of {owner} uses dim '{item}', which 'dims' does not define",
                        where(index),
                        did_you_mean(item, dims, "defined"),
                    )
                    ok = False
            elif isinstance(item, int) and not isinstance(item, bool) and item >= 1:
                shape.append(item)
            else:
                self.error("E305", f"shape of {owner}: each size must be an integer >= 1 or a dim name, got: {describe(item)}",
                           where(index))
                ok = False
        return tuple(shape) if ok else None

    def check_value(self, value: Any, loc: Location, dtype: str, shape: tuple[int, ...], what: str) -> np.ndarray | None:
        """A value for a variable (initial or a job's argument) as an array, or an error."""
        if isinstance(value, dict):
            self.error("E310", f"{what} must be a number or a list, got: a mapping", location_of(value, loc))
            return None
        found = _nested_shape(value)
        if found is None:
            self.error(
                "E311",
                f"{what} is a ragged list; rows must have equal lengths",
                location_of(value, loc),
                f"give a nested list of shape {_show_shape(shape)}",
            )
            return None
        if isinstance(value, list) and found != shape:
            self.error(
                "E312",
                f"{what} has shape {_show_shape(found)}, but the variable's shape is {_show_shape(shape)}",
                location_of(value, loc),
                f"give a nested list of shape {_show_shape(shape)}, or one number for every element",
            )
            return None
        leaves = list(_leaves(value))
        for leaf in leaves:
            problem = _leaf_problem(leaf, dtype)
            if problem:
                self.error("E313", f"{what}: {problem}", location_of(value, loc))
                return None
        try:
            array = np.asarray(leaves if not isinstance(value, list) else value, dtype=dtype).reshape(found)
        except (ValueError, TypeError, OverflowError) as exc:
            self.error("E313", f"{what} cannot be stored as {dtype}: {exc}", location_of(value, loc))
            return None
        # One number fills every element (a list has the shape already, checked above). An
        # empty array filled by broadcasting is what np.broadcast_to(...).copy() makes, faster.
        filled = np.empty(shape, dtype=array.dtype)
        filled[...] = array
        return filled

    def check_variables(self, top: YMap) -> None:
        variables = self.section(top, "variables", "e.g. variables: {q_m: {type: float64, shape: [NDOF]}}")
        if variables is None:
            return
        for key, value in variables.items():
            key_loc = variables.key_loc(key)
            name = self.name(key, key_loc, "variable")
            if name is None:
                continue
            self.var_locs[name] = key_loc
            # (a mapping, as nearly always, needs no location and no message: they are made for the error only)
            spec = value if isinstance(value, YMap) else self.mapping(
                value, variables.value_loc(key), f"variable '{name}'", "e.g. q_m: {type: float64, shape: [NDOF]}")
            if spec is None:
                continue
            where = f"in variable '{name}'"
            self.keys(spec, VARIABLE_KEYS, ("type",), where, key_loc)
            dtype: str | None = None
            if "type" in spec:
                raw = spec["type"]  # (its location is looked up only to report it)
                if not isinstance(raw, str):
                    self.text(raw, spec.value_loc("type"), f"type of variable '{name}'")
                elif raw not in DTYPES:
                    self.error("E303", f"variable '{name}' has unknown type '{raw}'", spec.value_loc("type"), did_you_mean(raw, DTYPES))
                else:
                    dtype = _dtype_name(raw)
            shape: tuple[int, ...] | None = ()
            if "shape" in spec and spec["shape"] is not None:
                shape = self.resolve_shape(spec["shape"], spec.value_loc("shape"), f"variable '{name}'")
            doc = ""
            if "doc" in spec and spec["doc"] is not None:
                doc = self.text(spec["doc"], spec.value_loc("doc"), f"doc of variable '{name}'") or ""
            obj: str | None = None
            if "object" in spec:
                obj = spec["object"]
                if not isinstance(obj, str):
                    obj = self.text(obj, spec.value_loc("object"), f"object type of variable '{name}'")
                if obj is not None:
                    self.var_object[name] = obj
            if "initial" in spec:
                self.var_initial.add(name)
                if dtype is not None and shape is not None:
                    initial = self.check_value(
                        spec["initial"], spec.value_loc("initial"), dtype, shape, f"initial value of variable '{name}'"
                    )
                    if initial is not None:
                        self.out.initial_values[name] = initial
            if dtype is None or shape is None:
                continue
            self.var_ok.add(name)
            initial = self.out.initial_values.get(name)
            if initial is not None:
                initial = initial.copy()
                initial.setflags(write=False)
            self.out.variables[name] = VariableSpec(name, len(self.out.variables), dtype, shape, doc, obj, key_loc, initial)

    # --- tasks ------------------------------------------------------------------------------

    def known_modules(self) -> list[str] | None:
        if self.module_names is None:
            return None
        try:
            return list(self.module_names())
        except Exception:  # a broken registry must not hide the user's mistake
            return None

    def check_tasks(self, top: YMap) -> None:
        tasks = self.section(top, "tasks", "e.g. tasks: {pid: {module: pid_joint, rtpu: rtpu0, period: 1 ms}}")
        if tasks is None:
            return
        for index, (key, value) in enumerate(tasks.items()):
            key_loc = tasks.key_loc(key)
            name = self.name(key, key_loc, "task")
            if name is None:
                continue
            self.task_names.add(name)
            # (a mapping, as nearly always, needs no location and no message: they are made for the error only)
            spec = value if isinstance(value, YMap) else self.mapping(
                value, tasks.value_loc(key), f"task '{name}'", "e.g. pid: {module: pid_joint, rtpu: rtpu0, period: 1 ms}")
            if spec is None:
                continue
            task = _Task(name, index, key_loc)
            self.tasks[name] = task
            self.keys(spec, TASK_KEYS, ("module", "rtpu"), f"in task '{name}'", key_loc)
            complete = self.check_task_fields(task, spec)
            module_class = self.check_task_module(task, spec)
            if module_class is not None:
                params_ok = self.check_task_params(task, spec, module_class)
                if not params_ok:
                    complete = False
                task.ok = self.check_task_ports(task, spec, module_class)
            if complete and task.ok:
                self.out.tasks[name] = TaskSpec(
                    name,
                    task.module,
                    task.rtpu,
                    task.period,
                    task.priority,
                    task.critical,
                    task.params,
                    tuple([PortBinding(b.port, b.variable, b.shape) for b in task.bindings]),
                    tuple([r for r, _ in task.resources]),
                    index,
                    key_loc,
                    task.wcet,
                    task.aperiodic,
                    task.min_interarrival,
                    dict(task.channels),
                )

    def check_task_fields(self, task: _Task, spec: YMap) -> bool:
        """rtpu, period/rate, priority, critical, resources; False if any is wrong."""
        ok = True
        name = task.name
        if "rtpu" in spec:
            rtpu = spec["rtpu"]  # (its location is looked up only to report it)
            if not isinstance(rtpu, str):
                self.text(rtpu, spec.value_loc("rtpu"), f"rtpu of task '{name}'")
                ok = False
            elif rtpu not in self.rtpu_names:
                self.error("E203", f"task '{name}' runs on RTPU '{rtpu}', which 'rtpus' does not declare", spec.value_loc("rtpu"),
                           did_you_mean(rtpu, self.rtpu_names, "declared"))
                ok = False
            else:
                task.rtpu = rtpu
        else:
            ok = False
        ok = self.check_task_timing(task, spec) and ok
        if "priority" in spec:
            priority = self.integer(spec["priority"], spec.value_loc("priority"), f"priority of task '{name}'")
            ok = ok and priority is not None
            task.priority = priority or 0
        if "critical" in spec:
            critical = self.boolean(spec["critical"], spec.value_loc("critical"), f"'critical' of task '{name}'")
            ok = ok and critical is not None
            task.critical = bool(critical)
        if "resources" in spec and spec["resources"] is not None:
            value = spec["resources"]
            loc = spec.value_loc("resources")
            if not isinstance(value, YList):
                self.error("E113", f"resources of task '{name}' must be a list of devices, got: {describe(value)}", location_of(value, loc), "e.g. resources: [arm, {device: adc0, channels: 6-7}]")
                return False
            seen: set[str] = set()
            for i, item in enumerate(value):
                item_loc = value.item_loc(i)
                claim = self.port_claim(item, item_loc, f"resource of task '{name}'", f"task '{name}'", allow_name=True)
                device = claim.device if claim is not None else None
                if device is None:
                    ok = False
                elif device not in self.device_names:
                    self.error("E208", f"task '{name}' uses device '{device}', which 'devices' does not declare", claim.loc, did_you_mean(device, self.device_names, "declared"))
                    ok = False
                elif device in seen:
                    self.error("E602", f"task '{name}' lists device '{device}' twice", item_loc)
                    ok = False
                elif device in self.out.devices and not self.channels_exist(claim, f"task '{name}'"):
                    ok = False
                else:
                    seen.add(device)
                    task.resources.append((device, item_loc))
                    if claim.channels is not None:
                        task.channels[device] = claim.channels
        return ok

    def check_task_timing(self, task: _Task, spec: YMap) -> bool:
        """period or rate, or aperiodic with min_interarrival; and wcet within the period."""
        name = task.name
        ok = True
        aperiodic = False
        if "aperiodic" in spec:
            flag = self.boolean(spec["aperiodic"], spec.value_loc("aperiodic"), f"'aperiodic' of task '{name}'")
            if flag is None:
                return False  # periodic or not is unknown: any further timing error would be a guess
            aperiodic = flag
        task.aperiodic = aperiodic
        if aperiodic:
            for key in ("period", "rate"):
                if key in spec:
                    self.error(
                        "E506",
                        f"task '{name}' is aperiodic, so it takes no {key}",
                        spec.key_loc(key),
                        "an aperiodic task runs when an event arrives; give its min_interarrival: instead (e.g. min_interarrival: 5 ms)",
                    )
                    ok = False
            if "min_interarrival" not in spec:
                self.error(
                    "E507",
                    f"aperiodic task '{name}' needs a min_interarrival",
                    spec.key_loc("aperiodic"),
                    "add the shortest time between two of its events, e.g. min_interarrival: 5 ms",
                )
                return False
            gap = self.quantity(spec["min_interarrival"], spec.value_loc("min_interarrival"), TIME, f"min_interarrival of task '{name}'")
            if gap is None:
                return False
            task.min_interarrival = gap
            task.period = gap  # the worst case: analysis treats it as periodic at its fastest
        else:
            if "min_interarrival" in spec:
                self.error(
                    "E508",
                    f"task '{name}' gives a min_interarrival but is not aperiodic",
                    spec.key_loc("min_interarrival"),
                    "add 'aperiodic: true' for a task released by events, or give a periodic task a period: or rate:",
                )
                ok = False
            if "period" in spec and "rate" in spec:
                self.error(
                    "E503",
                    f"task '{name}' gives both a period and a rate",
                    spec.key_loc("rate"),
                    "give one of them: period: 1 ms or rate: 1 kHz",
                )
                return False
            if "period" in spec:
                period = self.quantity(spec["period"], spec.value_loc("period"), TIME, f"period of task '{name}'")
                ok = ok and period is not None
                task.period = period or 0.0
            elif "rate" in spec:
                rate = self.quantity(spec["rate"], spec.value_loc("rate"), FREQUENCY, f"rate of task '{name}'")
                ok = ok and rate is not None
                task.period = 1.0 / rate if rate else 0.0
            else:
                self.error(
                    "E504",
                    f"task '{name}' needs a period or a rate",
                    task.loc,
                    "add e.g. 'period: 1 ms' or 'rate: 1 kHz', or 'aperiodic: true' with a min_interarrival:",
                )
                return False
        if "wcet" in spec:
            loc = spec.value_loc("wcet")
            wcet = self.quantity(spec["wcet"], loc, TIME, f"wcet of task '{name}'")
            if wcet is None:
                return False
            if ok and task.period > 0 and wcet > task.period:
                span = "min_interarrival" if aperiodic else "period"
                self.error(
                    "E505",
                    f"wcet of task '{name}' must be <= its {span} ({_ms(task.period)}), got: {spec['wcet']}",
                    loc,
                    "a cycle that runs longer than its period can never keep up; check the wcet, or slow the task down",
                )
                return False
            task.wcet = wcet
        return ok

    def check_task_module(self, task: _Task, spec: YMap) -> Any:
        if "module" not in spec:
            return None
        module = spec["module"]  # (its location is looked up only to report it)
        if not isinstance(module, str):
            self.text(module, spec.value_loc("module"), f"module of task '{task.name}'")
            return None
        task.module = module
        try:
            module_class = self.module_lookup(module)
        except Exception as exc:  # ModuleError, or a library that fails to import
            known = self.known_modules()
            hint = did_you_mean(module, known, "registered") if known is not None else str(exc)
            self.error("E207", f"task '{task.name}' uses module '{module}', which is not registered", spec.value_loc("module"), hint)
            return None
        return module_class

    def module_ports(self, task: _Task, module_class: Any, spec: YMap) -> tuple[PortSpec, ...] | None:
        try:
            # ports may depend on params (a data logger's inputs); without valid params, the class's
            built = getattr(task, "built_params", None)
            ports = tuple(module_class.ports_for(built) if built is not None else module_class.ports())
        except Exception as exc:  # the module is broken, not the YAML; say so
            self.error("E307", f"module '{task.module}' of task '{task.name}' cannot list its ports: {exc!r}", spec.value_loc("module"))
            return None
        return ports

    def port_shape(self, port: PortSpec, variable_shape: tuple[int, ...]) -> tuple[int, ...]:
        """`port.resolved_shape` with this file's dims; a declared shape is resolved once, not per task.

        Raises what `resolved_shape` raises (a shape that fails is never remembered).
        """
        declared = port.shape
        try:
            shape = self._port_shapes.get(declared) if declared is not None else None
        except TypeError:  # an unhashable declared shape: resolved afresh each time
            shape = declared = None
        if shape is None:
            shape = port.resolved_shape(self.out.dims, variable_shape)
            if declared is not None:
                self._port_shapes[declared] = shape
        return shape

    def check_task_ports(self, task: _Task, spec: YMap, module_class: Any) -> bool:
        name = task.name
        ports = self.module_ports(task, module_class, spec)
        if ports is None:
            return False
        declared = {p.name: p for p in ports}
        links: dict[str, tuple[str, Location]] = {}
        ok = True
        if "ports" in spec and spec["ports"] is not None:
            m = self.mapping(spec["ports"], spec.value_loc("ports"), f"ports of task '{name}'", "e.g. ports: {tau: tau_u}")
            if m is None:
                ok = False
            else:
                for port_name, var in m.items():
                    if port_name not in declared:
                        self.error(
                            "E212",
                            f"module '{task.module}' of task '{name}' has no port '{port_name}'",
                            m.key_loc(port_name),
                            did_you_mean(port_name, declared, "ports"),
                        )
                        ok = False
                        continue
                    var_loc = m.value_loc(port_name)
                    var_name = var if isinstance(var, str) else self.text(var, var_loc, f"variable of port '{port_name}' of task '{name}'")
                    if var_name is None:
                        ok = False
                        continue
                    links[port_name] = (var_name, var_loc)
        var_locs, var_ok, variables = self.var_locs, self.var_ok, self.out.variables
        for port in ports:
            link = links.get(port.name)
            explicit = link is not None
            var, loc = link if link is not None else (port.variable, task.loc)
            if var not in var_locs:
                if explicit:
                    self.error(
                        "E205",
                        f"task '{name}' links port '{port.name}' to variable '{var}', which 'variables' does not declare",
                        loc,
                        did_you_mean(var, self.var_locs, "declared"),
                    )
                else:
                    self.error(
                        "E206",
                        f"task '{name}' (module '{task.module}') links port '{port.name}' by default to variable '{var}', "
                        "which 'variables' does not declare",
                        loc,
                        f"declare '{var}' under variables, or link the port with ports: {{{port.name}: <variable>}}; "
                        + did_you_mean(var, self.var_locs, "declared"),
                    )
                ok = False
                continue
            if var not in var_ok:
                ok = False  # the variable itself is wrong and was reported
                continue
            variable = variables[var]
            if port.dtype == ANY_DTYPE:  # a port that takes whatever its variable is
                port = PortSpec(port.name, port.kind, port.variable, variable.dtype,
                                variable.shape if port.shape is None else port.shape, port.doc)
            try:
                shape = self.port_shape(port, variable.shape)
            except KeyError as exc:
                self.error(
                    "E304",
                    f"port '{port.name}' of module '{task.module}' (task '{name}') has shape {_show_shape(port.shape)} "
                    f"with dim {exc}, which 'dims' does not define",
                    loc,
                    did_you_mean(str(exc.args[0]), self.out.dims, "defined"),
                )
                ok = False
                continue
            except (TypeError, ValueError) as exc:
                self.error("E306", f"port '{port.name}' of module '{task.module}' has a bad shape {port.shape!r}: {exc}", loc)
                ok = False
                continue
            if port.dtype != variable.dtype:
                self.error(
                    "E301",
                    f"task '{name}' port '{port.name}' ({port.kind.value}) is {port.dtype}, but variable '{var}' is {variable.dtype}",
                    loc,
                    f"change the type of '{var}' (line {variable.loc.line}) or link the port to a {port.dtype} variable",
                )
                ok = False
                continue
            if shape != variable.shape:
                named = "" if shape == port.shape else f" = {_show_shape(port.shape)}"
                self.error(
                    "E302",
                    f"task '{name}' port '{port.name}' ({port.kind.value}) has shape {_show_shape(shape)}{named}, "
                    f"but variable '{var}' has shape {_show_shape(variable.shape)}",
                    loc,
                    f"change the shape of '{var}' (line {variable.loc.line}) or link the port to a variable of shape {_show_shape(shape)}",
                )
                ok = False
                continue
            task.bindings.append(_Binding(port, var, shape, loc))
        return ok

    def check_task_params(self, task: _Task, spec: YMap, module_class: Any) -> bool:
        raw = spec.get("params")
        if raw is not None and not isinstance(raw, YMap):
            self.error("E113", f"params of task '{task.name}' must be a mapping, got: {describe(raw)}", self.params_loc(task, spec), "e.g. params: {kp: 400, kd: 40}")
            return False
        values = plain(raw) if raw is not None else {}
        try:
            task.built_params = module_class.build_params(values)
        except ParamError as exc:
            self.error("E308", f"params of task '{task.name}' (module '{task.module}'): {exc}", self.params_loc(task, spec))
            return False
        except Exception as exc:  # a module's own validation may raise anything
            self.error("E308", f"params of task '{task.name}' (module '{task.module}') were refused: {exc!r}", self.params_loc(task, spec))
            return False
        task.params = values
        return True

    @staticmethod
    def params_loc(task: _Task, spec: YMap) -> Location:
        """Where a message about a task's params points: the params, or the task when it gives none."""
        return location_of(spec.get("params"), spec.value_loc("params") if "params" in spec else task.loc)

    # --- configurations, jobs, applications --------------------------------------------------

    def check_configurations(self, top: YMap) -> None:
        configs = self.section(top, "configurations", "e.g. configurations: {joint_pid: [robot, pid]}")
        if configs is None:
            return
        for key, value in configs.items():
            key_loc = configs.key_loc(key)
            name = self.name(key, key_loc, "configuration")
            if name is None:
                continue
            self.config_names.add(name)
            if not isinstance(value, YList):
                loc = configs.value_loc(key)
                self.error("E113", f"configuration '{name}' must be a list of task names, got: {describe(value)}", location_of(value, loc), f"e.g. {name}: [robot, pid]")
                continue
            members: list[tuple[str, Location]] = []
            first: dict[str, Location] = {}
            modules: dict[str, tuple[str, Location]] = {}
            ok = True
            for i, item in enumerate(value):
                item_loc = value.item_loc(i)
                task = item if isinstance(item, str) else self.text(item, item_loc, f"task of configuration '{name}'")
                if task is None:
                    ok = False
                    continue
                if task not in self.task_names:
                    self.error("E209", f"configuration '{name}' names task '{task}', which 'tasks' does not declare", item_loc, did_you_mean(task, self.task_names, "declared"))
                    ok = False
                    continue
                if task in first:
                    self.error(
                        "E402",
                        f"task '{task}' appears twice in configuration '{name}' (first at line {first[task].line}, column {first[task].column})",
                        item_loc,
                        "a task runs at most once in a configuration; to run its module twice, declare a second task",
                    )
                    ok = False
                    continue
                module = self.tasks[task].module if task in self.tasks else ""
                if module and module in modules:
                    other, other_loc = modules[module]
                    self.error(
                        "E407",
                        f"configuration '{name}' runs module '{module}' twice: as task '{other}' (line {self.tasks[other].loc.line}) "
                        f"and as task '{task}' (line {self.tasks[task].loc.line})",
                        item_loc,
                        "a module runs at most once in a configuration (TR §3, Onika §4.3.2); "
                        "combine the two tasks into one, or use distinct modules",
                    )
                    ok = False
                    # still a member: what it writes counts, so no follow-on "nobody writes it" (E403),
                    # and no follow-on "two writers" (E401) with the task it repeats
                    first[task] = item_loc
                    members.append((task, item_loc))
                    self.config_repeats.setdefault(name, set()).add(task)
                    continue
                if module:
                    modules[module] = (task, item_loc)
                first[task] = item_loc
                members.append((task, item_loc))
            self.config_members[name] = members
            self.config_locs[name] = key_loc
            if ok:
                self.out.configurations[name] = ConfigurationSpec(name, tuple(t for t, _ in members), key_loc)

    def job_written(self) -> set[str]:
        """Variables job control writes (objects and initial values): the same for every configuration."""
        cached = getattr(self, "_job_written", None)
        if cached is None:
            cached = self._job_written = set(self.var_object) | self.var_initial
        return cached

    def check_data_flow(self, config: str) -> None:
        """Inputs have one writer; no variable two; consts come from init-time writers; exclusive devices."""
        members = [self.tasks[t] for t, _ in self.config_members.get(config, []) if t in self.tasks]
        # A task with an unresolved port may be the missing writer: report no "nobody writes it"
        # errors then, only what the resolved links prove.
        repeats = self.config_repeats.get(config, set())
        complete = all(t.ok for t in members if t.name not in repeats) and len(members) == len(self.config_members.get(config, []))
        # A repeated module's task (E407) is not judged again: its writes satisfy readers (no
        # follow-on E403/E405), but are not counted as second writers (E401) or as the kind of
        # write a const needs (E404); its own reads repeat the first task's.
        writers: dict[str, list[tuple[_Task, _Binding]]] = {}
        repeat_written: set[str] = set()
        for task in members:
            for b in task.bindings:
                if not b.port.kind.is_input:
                    if task.name in repeats:
                        repeat_written.add(b.variable)
                    else:
                        writers.setdefault(b.variable, []).append((task, b))
        for var, ws in writers.items():
            if len(ws) > 1:
                detail = _and_list([f"'{t.name}' (line {b.loc.line})" for t, b in ws])
                count = "two" if len(ws) == 2 else str(len(ws))
                self.error("E401", f"variable '{var}' has {count} writers in configuration '{config}': {detail}", ws[1][1].loc, _JOIN_HINT)
        job_written = self.job_written()
        for task in members:
            if task.name in repeats:
                continue
            for b in task.bindings:
                if not b.port.kind.is_input:
                    continue
                ws = writers.get(b.variable, [])
                if not ws and b.variable in repeat_written:
                    continue
                if not ws and b.variable not in job_written:
                    if not complete:
                        continue
                    self.error(
                        "E403",
                        f"task '{task.name}' reads {b.port.kind.value} '{b.variable}', but no task in configuration '{config}' writes it",
                        b.loc,
                        (did_you_mean(b.variable, written, "written") if (written := sorted(set(writers) | job_written))
                         else "nothing is written")
                        + f"; add a task that writes '{b.variable}', or give it an initial: value",
                    )
                    continue
                if not b.port.kind.needs_initial_value or b.variable in self.var_initial:
                    continue
                if ws and not any(w.port.kind.supplies_initial_value for _, w in ws):
                    w_task, w_binding = ws[0]
                    self.error(
                        "E404",
                        f"task '{task.name}' reads {b.port.kind.value} '{b.variable}' before its init, but its writer '{w_task.name}' "
                        f"in configuration '{config}' writes it as {w_binding.port.kind.value} (only after each cycle)",
                        b.loc,
                        f"make port '{w_binding.port.name}' of module '{w_task.module}' out-const or out-both, "
                        f"or give variable '{b.variable}' an initial: value",
                    )
                elif not ws and complete:
                    self.error(
                        "E405",
                        f"task '{task.name}' reads {b.port.kind.value} '{b.variable}' before its init, but in configuration '{config}' "
                        "only job control sets it, as a job's object, after tasks are spawned",
                        b.loc,
                        f"give variable '{b.variable}' an initial: value",
                    )
        self.check_device_claims(config, members)

    # --- who holds which device (TR §4.6.1) ---------------------------------------------------

    def claims_of(self, task: _Task) -> list[_Claim]:
        """What opening each of its resources takes: the device (its channels, or all of a port-based
        device's), and, for a sensor wired through io:, the I/O device's channels too."""
        cached = self._claims.get(task.name)
        if cached is not None:
            return cached
        claims: list[_Claim] = []
        for device, loc in task.resources:
            channels: tuple[int, ...] | None = task.channels.get(device)
            via: str | None = None
            seen: set[str] = set()
            while device in self.out.devices and device not in seen:
                seen.add(device)
                if channels is None:
                    ports = self.ports_of(device)
                    channels = tuple(range(ports)) if ports else None
                claims.append(_Claim(task.name, device, channels, loc, via))
                io = self.out.devices[device].io
                if io is None:
                    break
                via = via or device
                device, channels = io.device, io.channels
        self._claims[task.name] = claims
        return claims

    def _conflict(self, a: _Claim, b: _Claim) -> str:
        """'' if two claims of different tasks can be held together; else 'exclusive' or the shared channels."""
        if a.task == b.task or a.device != b.device:
            return ""
        spec = self.out.devices.get(a.device)
        if spec is not None and spec.exclusive:
            return "exclusive"
        if a.channels is None or b.channels is None:
            return ""
        return format_channels(set(a.channels) & set(b.channels))

    def check_device_claims(self, config: str, members: list[_Task]) -> None:
        """An exclusive device has one user (E601); a channel has one user (E603), in each configuration."""
        claims = [c for task in members for c in self.claims_of(task)]
        users: dict[str, list[_Claim]] = {}
        for claim in claims:
            spec = self.out.devices.get(claim.device)
            if spec is not None and spec.exclusive and all(u.task != claim.task for u in users.get(claim.device, [])):
                users.setdefault(claim.device, []).append(claim)
        for device, us in users.items():
            if len(us) > 1:
                self.error(
                    "E601",
                    f"device '{device}' is exclusive, but configuration '{config}' gives it to {_and_list([u.who() for u in us])}",
                    us[1].loc,
                    "an exclusive device has one user per configuration; move one task to another configuration, "
                    "or set exclusive: false if the driver can be shared",
                )
        for j, later in enumerate(claims):
            for earlier in claims[:j]:
                shared = self._conflict(earlier, later)
                if shared and shared != "exclusive":
                    self.error(
                        "E603",
                        f"device '{later.device}': {later.who()} claims channels {format_channels(later.channels or ())}, but "
                        f"{earlier.who()} holds {format_channels(earlier.channels or ())} in configuration '{config}'; "
                        f"they overlap on {shared}",
                        later.loc,
                        _disjoint_hint(earlier, later),
                    )

    def check_device_union(self) -> None:
        """W601: two tasks that no configuration has together, but that cannot hold their devices at once.

        A dynamic run spawns every task at start (TR §4.4), and a task opens its devices in init,
        so the second one's init would be refused.
        """
        tasks = [t for t in self.tasks.values() if t.resources]
        if len(tasks) < 2:
            return  # no two tasks open devices: nothing can clash (and no pairs of members to list)
        together = {frozenset((a, b)) for members in self.config_members.values()
                    for i, (a, _) in enumerate(members) for b, _ in members[i + 1:]}
        reported: set[frozenset[str]] = set()
        for i, first in enumerate(tasks):
            for second in tasks[i + 1:]:
                pair = frozenset((first.name, second.name))
                if pair in together or pair in reported:
                    continue
                for a in self.claims_of(first):
                    b = next((b for b in self.claims_of(second) if self._conflict(a, b)), None)
                    if b is None:
                        continue
                    shared = self._conflict(a, b)
                    what = "it is exclusive" if shared == "exclusive" else f"both need channels {shared}"
                    reported.add(pair)
                    self.warn(
                        "W601",
                        f"tasks {a.who()} and {b.who()} both open device '{a.device}' ({what}); no configuration has both, "
                        "but a dynamic run spawns every task at start, so the second one's init will be refused",
                        b.loc,
                        "run with --static (only the current configuration's tasks exist), or give each task its own "
                        "device or channels",
                    )
                    break

    def check_spins(self) -> None:
        """E509: an RTPU's spin before a release must be shorter than its shortest period, or it
        never sleeps: it would spin through every period, a whole CPU for nothing."""
        shortest: dict[str, _Task] = {}
        for task in self.tasks.values():
            if task.rtpu and task.period > 0 and not task.aperiodic:
                if task.rtpu not in shortest or task.period < shortest[task.rtpu].period:
                    shortest[task.rtpu] = task
        for rtpu in self.out.rtpus:
            task = shortest.get(rtpu.name)
            if task is not None and rtpu.spin >= task.period:
                self.error(
                    "E509",
                    f"spin of RTPU '{rtpu.name}' must be shorter than the shortest period of its tasks "
                    f"({_ms(task.period)}, task '{task.name}'), got: {_ms(rtpu.spin)}",
                    rtpu.spin_loc,
                    "the executive sleeps until `spin` before each release and spins the rest; "
                    "the default, 200 us, hid the wake-up latency of the machine in docs/performance.md; "
                    "`python -m bench.wait` measures yours",
                )

    def check_schedulability(self) -> None:
        """Warn where the declared wcets of one RTPU's tasks in a configuration cannot be guaranteed.

        Only tasks that declare `wcet:` count; an aperiodic task counts at its min_interarrival
        (a sporadic task at its fastest). For each RTPU and configuration, with U = Σ wcet_i / T_i
        over its n tasks:

        - U > 1 (W502): overloaded; no scheduler meets every deadline.
        - else U > n(2^(1/n) - 1) (W501): beyond Liu & Layland's rate-monotonic bound, so
          fixed rate-monotonic priorities are not guaranteed (the test is sufficient, not necessary).
        - the critical tasks, U_c > 1 (W503): the executive runs maximum-urgency-first (Stewart &
          Khosla): critical tasks always before the others, earliest deadline first among them.
          With EDF inside the critical set, MUF guarantees that set when it fits the processor
          on its own, U_c <= 1. We apply that test, not the RM bound n_c(2^(1/n_c) - 1), because
          the executive orders critical tasks by deadline, not by rate. It ignores blocking: the
          executive does not preempt a cycle, so a long non-critical cycle can still delay a
          critical release by up to its wcet.
        """
        seen: set[tuple[str, frozenset[str]]] = set()
        for config, members in self.config_members.items():
            by_rtpu: dict[str, list[_Task]] = {}
            for task_name, _ in members:
                task = self.tasks.get(task_name)
                if task is not None and task.rtpu and task.period > 0:
                    by_rtpu.setdefault(task.rtpu, []).append(task)
            loc = self.config_locs.get(config, NOWHERE)
            for rtpu, tasks in by_rtpu.items():
                timed = [t for t in tasks if t.wcet is not None]
                key = (rtpu, frozenset(t.name for t in timed))
                if not timed or key in seen:
                    continue
                seen.add(key)
                untimed = [t.name for t in tasks if t.wcet is None]
                note = f"; tasks without a wcet ({', '.join(untimed)}) only add to it" if untimed else ""
                total = sum(_utilisation(t) for t in timed)
                n = len(timed)
                bound = n * (2 ** (1 / n) - 1)
                where = f"RTPU '{rtpu}' in configuration '{config}'"
                if total > 1:
                    self.warn(
                        "W502",
                        f"{where} is overloaded: {_loads(timed)}; U = {total:.3f} > 1",
                        loc,
                        "no schedule meets every deadline; move a task to another RTPU, lengthen a period or shorten a cycle" + note,
                    )
                elif total > bound:
                    self.warn(
                        "W501",
                        f"{where} exceeds the rate-monotonic bound: {_loads(timed)}; U = {total:.3f} > {bound:.3f} = n(2^(1/n) - 1) for n = {n}",
                        loc,
                        "Liu & Layland's test cannot guarantee these deadlines (it is sufficient, not necessary); "
                        "move a task to another RTPU or lengthen a period" + note,
                    )
                critical = [t for t in tasks if t.critical]
                if critical and all(t.wcet is not None for t in critical):
                    critical_total = sum(_utilisation(t) for t in critical)
                    if critical_total > 1:
                        self.warn(
                            "W503",
                            f"critical tasks of {where} are not guaranteed: {_loads(critical)}; U_critical = {critical_total:.3f} > 1",
                            loc,
                            "maximum-urgency-first (Stewart & Khosla) guarantees the critical set only when it fits the RTPU "
                            "on its own (EDF within the set); make fewer tasks critical, or spread them over RTPUs",
                        )

    def check_const_order(self) -> None:
        """Producers of consts start before their readers, across every task; a cycle is an error."""
        tasks = [t for t in self.tasks.values() if t.ok]
        producers: dict[str, list[_Task]] = {}
        for task in tasks:
            for b in task.bindings:
                if b.port.kind.supplies_initial_value:
                    producers.setdefault(b.variable, []).append(task)
        graph: dict[str, set[str]] = {t.name: set() for t in tasks}
        via: dict[tuple[str, str], str] = {}
        for task in tasks:
            for b in task.bindings:
                if b.port.kind.needs_initial_value:
                    for producer in producers.get(b.variable, []):
                        graph[task.name].add(producer.name)
                        via.setdefault((producer.name, task.name), b.variable)
        sorter = graphlib.TopologicalSorter(graph)
        try:
            sorter.prepare()
        except graphlib.CycleError as exc:
            cycle: list[str] = list(exc.args[1])
            links = "; ".join(
                f"'{a}' writes '{via.get((a, b), '?')}' that '{b}' reads before its init" for a, b in zip(cycle, cycle[1:])
            )
            self.error(
                "E406",
                f"const dependencies form a cycle: {' -> '.join(cycle)}",
                self.tasks[cycle[0]].loc,
                f"{links}; break the cycle by making one of these ports a var (in-var/out-var)",
            )
            return
        index = {t.name: t.index for t in tasks}
        ready: list[tuple[int, str]] = []
        order: list[str] = []
        while sorter.is_active():
            for name in sorter.get_ready():
                heapq.heappush(ready, (index[name], name))
            _, name = heapq.heappop(ready)
            order.append(name)
            sorter.done(name)
        self.out.init_order = tuple(order)

    def check_expression(self, value: Any, loc: Location, what: str) -> str | None:
        """A job condition in the restricted language of `_expressions`, naming declared variables."""
        text = self.text(value, loc, what)
        if text is None:
            return None
        example = 'e.g. "max(abs(q_m - q_d)) < 1e-3"'
        try:
            condition = compile_condition(text)
        except ExpressionError as exc:
            where = self.inside_scalar(loc, text, exc.offset)
            if exc.syntax:
                self.error("E702", f"{what} is not an expression: {exc.message}: {text!r}", where, example)
            else:
                self.error(
                    "E703",
                    f"{what}: {exc.message} (column {exc.offset + 1} of {text!r})",
                    where,
                    f"a condition may use {ALLOWED}",
                )
            return None
        self.expression_names.update(condition.variables)
        unknown = sorted(condition.variables - set(self.var_locs))
        for name in unknown:
            offset = _name_offset(text, name)
            self.error(
                "E704",
                f"{what} uses '{name}', which 'variables' does not declare",
                self.inside_scalar(loc, text, offset),
                did_you_mean(name, self.var_locs, "declared"),
            )
        return None if unknown else text

    def inside_scalar(self, loc: Location, text: str, offset: int) -> Location:
        """Where character `offset` of a one-line scalar `text` written at `loc` is, if the file shows it.

        The YAML node's location is its first character: the quote of a quoted scalar. Escapes
        or a block scalar make the written text differ from the value; then `loc` it is.
        """
        line = self.source_line(loc)
        if line is None or "\n" in text:
            return loc
        start = loc.column - 1
        for skip in (1, 0) if line[start:start + 1] in ("'", '"') else (0,):
            if line[start + skip:start + skip + len(text)] == text:
                return Location(loc.file, loc.line, loc.column + skip + offset)
        return loc

    def source_line(self, loc: Location) -> str | None:
        if loc.file not in self.sources:
            try:
                with open(loc.file, encoding="utf-8-sig") as stream:
                    self.sources[loc.file] = stream.read().splitlines()
            except (OSError, UnicodeError):
                self.sources[loc.file] = []
        lines = self.sources[loc.file]
        return lines[loc.line - 1] if 0 < loc.line <= len(lines) else None

    def check_jobs(self, top: YMap) -> None:
        jobs = self.section(top, "jobs", "e.g. jobs: {move: {configuration: joint_pid, object: q_d}}")
        if jobs is None:
            return
        for key, value in jobs.items():
            key_loc = jobs.key_loc(key)
            name = self.name(key, key_loc, "job")
            if name is None:
                continue
            self.job_names.add(name)
            spec = self.mapping(value, jobs.value_loc(key), f"job '{name}'", "e.g. move: {configuration: joint_pid, object: q_d}")
            if spec is None:
                continue
            self.keys(spec, JOB_KEYS, ("configuration",), f"in job '{name}'", key_loc)
            ok = "configuration" in spec
            config = None
            if "configuration" in spec:
                loc = spec.value_loc("configuration")
                config = self.text(spec["configuration"], loc, f"configuration of job '{name}'")
                if config is not None and config not in self.config_names:
                    self.error("E210", f"job '{name}' runs configuration '{config}', which 'configurations' does not declare", loc, did_you_mean(config, self.config_names, "declared"))
                    ok = False
                ok = ok and config is not None
            obj = None
            if "object" in spec and spec["object"] is not None:
                loc = spec.value_loc("object")
                obj = self.text(spec["object"], loc, f"object of job '{name}'")
                if obj is not None and obj not in self.var_locs:
                    self.error("E213", f"job '{name}' takes object '{obj}', which 'variables' does not declare", loc, did_you_mean(obj, self.var_object or self.var_locs, "objects"))
                    ok = False
                elif obj is not None and obj not in self.var_object:
                    self.error(
                        "E701",
                        f"job '{name}' takes variable '{obj}' as its object, but the variable is not marked as an object",
                        loc,
                        f"add 'object: <type>' to variable '{obj}' (line {self.var_locs[obj].line})",
                    )
                    ok = False
                ok = ok and obj is not None
            pre = post = None
            if "pre" in spec and spec["pre"] is not None:
                pre = self.check_expression(spec["pre"], spec.value_loc("pre"), f"pre-condition of job '{name}'")
                ok = ok and pre is not None
            if "post" in spec and spec["post"] is not None:
                post = self.check_expression(spec["post"], spec.value_loc("post"), f"post-condition of job '{name}'")
                ok = ok and post is not None
            timeout = None
            if "timeout" in spec and spec["timeout"] is not None:
                timeout = self.quantity(spec["timeout"], spec.value_loc("timeout"), TIME, f"timeout of job '{name}'")
                ok = ok and timeout is not None
            if ok and config is not None:
                self.out.jobs[name] = JobSpec(name, config, obj, pre, post, timeout, key_loc)

    def check_applications(self, top: YMap) -> None:
        """Steps interlock (Onika §4.4.1-4.4.2); applications nest without cycles; gaps make them incomplete."""
        apps = self.section(top, "applications", "e.g. applications: {demo: [move, {move: {q_d: [0, 0, 0]}}]}")
        if apps is None:
            return
        entries: list[tuple[str, Location, Any, Location]] = []
        for key, value in apps.items():
            key_loc = apps.key_loc(key)
            name = self.name(key, key_loc, "application")
            if name is None:
                continue
            if name in self.job_names:
                self.error(
                    "E214",
                    f"'{name}' names both a job and an application",
                    key_loc,
                    "a step names a job or an application, so their names must differ; rename one",
                )
                continue
            self.app_names.add(name)
            entries.append((name, key_loc, value, apps.value_loc(key)))
        parsed: dict[str, tuple[list[ApplicationStep], set[int], Location]] = {}
        for name, key_loc, value, loc in entries:
            if not isinstance(value, YList):
                self.error("E113", f"application '{name}' must be a list of job steps, got: {describe(value)}", location_of(value, loc), f"e.g. {name}: [move, {{move: {{q_d: [0, 0, 0]}}}}]")
                continue
            steps: list[ApplicationStep] = []
            gaps: set[int] = set()  # step numbers whose job lacks its object
            ok = True
            for i, item in enumerate(value):
                checked = self.check_step(name, i + 1, item, value.item_loc(i))
                if checked is None:
                    ok = False
                    continue
                step, gap = checked
                steps.append(step)
                if gap:
                    gaps.add(i + 1)
            if ok:
                parsed[name] = (steps, gaps, key_loc)
        graph = {name: {s.job for s in steps if s.is_application} for name, (steps, _, _) in parsed.items()}
        order = self.application_order(graph, {name: loc for name, _, _, loc in entries}, {name: k for name, k, _, _ in entries})
        complete: dict[str, bool] = {}
        for name in order:
            steps, gaps, key_loc = parsed[name]
            whole = not gaps
            for number, step in enumerate(steps, 1):
                if step.is_application and step.job in complete and not complete[step.job]:
                    whole = False
                    self.warn(
                        "W702",
                        f"application '{name}' is incomplete: step {number} '{step.job}' is the incomplete application '{step.job}'",
                        step.loc,
                        f"fill the gaps of '{step.job}' first; an incomplete application may be kept but not run",
                    )
            complete[name] = whole
            self.out.applications[name] = ApplicationSpec(name, tuple(steps), key_loc, whole)

    def application_order(self, graph: dict[str, set[str]], locs: dict[str, Location], key_locs: dict[str, Location]) -> list[str]:
        """Applications with the ones they use first; those on a cycle are reported and left out."""
        known = {name: {s for s in subs if s in graph} for name, subs in graph.items()}
        sorter = graphlib.TopologicalSorter(known)
        try:
            return list(sorter.static_order())
        except graphlib.CycleError as exc:
            cycle: list[str] = list(reversed(exc.args[1]))  # graphlib lists it from user to used
            self.error(
                "E708",
                f"applications form a cycle: {' -> '.join(cycle)}",
                key_locs.get(cycle[0], locs.get(cycle[0], NOWHERE)),
                "an application may use another as a step, but never itself, directly or through others",
            )
            on_cycle = set(cycle)
            rest = {n: subs for n, subs in known.items() if n not in on_cycle}
            # whatever uses a broken application cannot be built either
            changed = True
            while changed:
                changed = False
                for n in list(rest):
                    if rest[n] - set(rest):
                        del rest[n]
                        changed = True
            return self.application_order(rest, locs, key_locs) if rest else []

    def check_step(self, app: str, number: int, item: Any, loc: Location) -> tuple[ApplicationStep, bool] | None:
        """One step and whether it leaves a gap (a job without its object); None if it is wrong."""
        args: Any = None
        args_loc = loc
        if isinstance(item, str):
            job = item
        elif isinstance(item, YMap) and len(item) == 1:
            key = next(iter(item))
            job_name = self.text(key, item.key_loc(key), f"job of step {number} of application '{app}'")
            if job_name is None:
                return None
            job = job_name
            loc = item.key_loc(key)
            args = item[key]
            args_loc = item.value_loc(key)
        else:
            self.error(
                "E113",
                f"step {number} of application '{app}' must be a job name or {{job: {{object: value}}}}, got: {describe(item)}",
                location_of(item, loc),
                "e.g. - move: {q_d: [0, -0.5, 0.5, 0, 0, 0]}",
            )
            return None
        if job not in self.job_names and job in self.app_names:
            if args is not None:
                self.error(
                    "E709",
                    f"step {number} of application '{app}' gives objects to application '{job}', which takes none",
                    location_of(args, args_loc),
                    f"give the objects to the steps inside application '{job}'",
                )
                return None
            return ApplicationStep(job, {}, loc, is_application=True), False
        if job not in self.job_names:
            self.error("E211", f"step {number} of application '{app}' runs job '{job}', which 'jobs' does not declare", loc,
                       did_you_mean(job, self.job_names | self.app_names, "jobs and applications"))
            return None
        spec = self.out.jobs.get(job)
        if spec is None:
            return None  # the job itself is wrong, and was reported there
        arguments: dict[str, Any] = {}
        if args is not None:
            m = self.mapping(args, args_loc, f"arguments of job '{job}' in application '{app}'", "e.g. move: {q_d: [0, 0, 0]}")
            if m is None:
                return None
            names = list(m)
            if names and spec.object is None:
                self.error(
                    "E705",
                    f"step {number} of application '{app}' gives object '{names[0]}' to job '{job}', which takes no object",
                    m.key_loc(names[0]),
                    f"remove the object, or give job '{job}' an object: in 'jobs'",
                )
                return None
            kind = self.var_object.get(str(spec.object), "?")
            if len(names) > 1:
                self.error(
                    "E706",
                    f"step {number} of application '{app}' gives {len(names)} objects to job '{job}' "
                    f"({', '.join(str(n) for n in names)}), but a job takes exactly one",
                    m.key_loc(names[1]),
                    f"job '{job}' takes its object '{spec.object}' (type {kind}); give only that one",
                )
                return None
            for var, val in m.items():
                if var != spec.object:
                    self.error(
                        "E707",
                        f"step {number} of application '{app}' gives '{var}' to job '{job}', but its object is '{spec.object}' (type {kind})",
                        m.key_loc(var),
                        f"write '- {job}: {{{spec.object}: <value>}}'",
                    )
                    return None
                variable = self.out.variables.get(str(var))
                if variable is None:
                    return None  # the job's own object is wrong, and was reported there
                array = self.check_value(val, m.value_loc(var), variable.dtype, variable.shape, f"object '{var}' of step {number} of application '{app}'")
                if array is None:
                    return None
                arguments[str(var)] = plain(val)
        gap = bool(spec.object) and spec.object not in arguments
        if gap:
            self.warn(
                "W701",
                f"application '{app}' is incomplete: step {number} '{job}' needs an object of type {self.var_object.get(str(spec.object), '?')}",
                loc,
                f"give it as '- {job}: {{{spec.object}: <value>}}'; an incomplete application may be kept but not run",
            )
        return ApplicationStep(job, arguments, loc), gap

    def check_unused(self) -> None:
        in_a_config = {t for members in self.config_members.values() for t, _ in members}
        for task in self.tasks.values():
            if task.name not in in_a_config:
                self.warn("W201", f"task '{task.name}' is in no configuration", task.loc, "it is spawned but never turned on; add it to a configuration or remove it")
        if any(not t.ok for t in self.tasks.values()):
            return  # who reads what is unknown while a task's ports are unknown
        read = {b.variable for t in self.tasks.values() for b in t.bindings if b.port.kind.is_input}
        for name, loc in self.var_locs.items():
            if name not in read and name not in self.expression_names:
                self.warn("W202", f"variable '{name}' is read by no task", loc, "remove it, or link a task's input port to it")


def _disjoint_hint(holder: _Claim, claimant: _Claim) -> str:
    """How to give `claimant` channels `holder` does not hold."""
    free = sorted(set(claimant.channels or ()) - set(holder.channels or ()))
    hint = "a channel has one user per configuration: give the tasks disjoint channels"
    if not free or claimant.via:
        return hint
    shown = format_channels(free)
    value = shown if ", " not in shown else f"[{shown}]"
    return f"{hint}, e.g. for '{claimant.task}': {{device: {claimant.device}, channels: {value}}}"


def _utilisation(task: _Task) -> float:
    return (task.wcet or 0.0) / task.period


def _loads(tasks: Sequence[_Task]) -> str:
    """'traj 0.400 (0.8 ms / 2 ms), pid 0.500 (0.5 ms / 1 ms)'."""
    return ", ".join(f"{t.name} {_utilisation(t):.3f} ({_ms(t.wcet or 0.0)} / {_ms(t.period)})" for t in tasks)


def _name_offset(text: str, name: str) -> int:
    """Where `name` first appears in `text` as a whole word; 0 if it cannot be found."""
    match = re.search(rf"(?<![A-Za-z0-9_]){re.escape(name)}(?![A-Za-z0-9_])", text)
    return match.start() if match else 0


def _nested_shape(value: Any) -> tuple[int, ...] | None:
    """The shape of a nested list, () for a scalar, None if ragged."""
    if not isinstance(value, list):
        return ()
    if not value:
        return (0,)
    inner = [_nested_shape(v) for v in value]
    if any(s is None or s != inner[0] for s in inner):
        return None
    first = inner[0]
    assert first is not None
    return (len(value), *first)


def _leaves(value: Any) -> Iterable[Any]:
    if isinstance(value, list):
        for v in value:
            yield from _leaves(v)
    else:
        yield value


_INT_RANGE = {"int32": (-(2**31), 2**31 - 1), "int64": (-(2**63), 2**63 - 1), "uint8": (0, 255)}


def _leaf_problem(leaf: Any, dtype: str) -> str:
    if dtype == "bool":
        return "" if isinstance(leaf, bool) else f"bool elements must be true or false, got: {describe(leaf)}"
    if isinstance(leaf, bool) or not isinstance(leaf, (int, float)):
        return f"{dtype} elements must be numbers, got: {describe(leaf)}"
    if dtype in _INT_RANGE:
        if not isinstance(leaf, int):
            return f"{dtype} elements must be integers, got: {describe(leaf)}"
        low, high = _INT_RANGE[dtype]
        if not low <= leaf <= high:
            return f"{dtype} elements must lie in [{low}, {high}], got: {leaf}"
    return ""


def check_document(
    doc: Any,
    file: str,
    module_lookup: ModuleLookup,
    module_names: Callable[[], Iterable[str]] | None = None,
    driver_lookup: DriverLookup | None = None,
) -> Checked:
    """Check a loaded document; never raises for anything in the document.

    `driver_lookup` finds a driver class by name (the registry by default): what it declares
    (channels, the I/O device it reads through, its options) is checked against the YAML.
    """
    checker = _Checker(file, module_lookup, module_names, driver_lookup)
    doc_loc = Location(file, 1, 1) if file else NOWHERE
    try:
        return checker.run(doc, doc_loc)
    except Exception as exc:  # a bug here must still end as a message, never a traceback for the user
        checker.error(
            "E901",
            f"internal error in the checker: {exc!r}",
            doc_loc,
            "please report this with the file you checked",
        )
        return checker.out
