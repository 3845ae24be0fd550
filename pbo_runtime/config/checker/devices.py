"""Devices: each device's spec, its driver's own check of its options, channel claims, and the
wiring of a sensor to the I/O device it reads through (io:).
"""

from __future__ import annotations

from typing import Any

from pbo_runtime.config.channels import EXAMPLE as CHANNELS_EXAMPLE
from pbo_runtime.config.channels import ChannelError, format_channels, parse_channels
from pbo_runtime.config.checker.base import CheckerBase, named_by
from pbo_runtime.config.checker.model import CLAIM_KEYS, DEVICE_KEYS
from pbo_runtime.config.checker.words import describe, did_you_mean
from pbo_runtime.config.model import DeviceSpec, Location, PortClaim
from pbo_runtime.config.yaml_nodes import YMap, location_of, plain
from pbo_runtime.objects import registry


class DeviceChecks(CheckerBase):
    """Rules for `devices:`, and the driver lookups and channel checks tasks share."""

    def check_devices(self, top: YMap) -> None:
        for name, value, key_loc, value_loc in self.entries(
            top, "devices", "device", "e.g. devices: {arm: {driver: mujoco_arm, exclusive: true}}"
        ):
            self.device_names.add(name)
            spec = self.mapping(value, value_loc, f"device '{name}'", "e.g. arm: {driver: mujoco_arm, exclusive: true}")
            if spec is None:
                continue
            self.device_nodes[name] = spec
            if "driver" not in spec:
                self.error(
                    "E112",
                    f"device '{name}' has no 'driver:', which is required",
                    key_loc,
                    "add 'driver: <name>' (a registered driver)",
                )
                continue
            driver = self.text(spec["driver"], spec.value_loc("driver"), f"driver of device '{name}'")
            if driver is not None and not self.driver_registered(name, driver, spec.value_loc("driver")):
                continue
            exclusive: bool | None = False
            if "exclusive" in spec:
                exclusive = self.boolean(spec["exclusive"], spec.value_loc("exclusive"), f"'exclusive' of device '{name}'")
            io: PortClaim | None = None
            io_ok = True
            if "io" in spec:
                io = self.port_claim(
                    spec["io"], spec.value_loc("io"), f"io of device '{name}'", f"device '{name}' (io:)", allow_name=False
                )
                io_ok = io is not None
            options = {k: plain(v) for k, v in spec.items() if k not in DEVICE_KEYS}
            bad = [k for k in options if not isinstance(k, str)]
            for k in bad:
                self.error("E118", f"option names of device '{name}' must be text, got: {describe(k)}", spec.key_loc(k))
            if driver is not None and not bad and not self.driver_accepts(name, driver, options, key_loc, spec):
                continue
            if driver is not None and exclusive is not None and not bad and io_ok:
                self.out.devices[name] = DeviceSpec(name, driver, exclusive, options, key_loc, io)
        self.check_device_wiring()

    # --- devices: drivers, channels, wiring -------------------------------------------------

    def driver_class(self, driver: str) -> Any:
        """The registered driver class, or None when it cannot be found (reported at the device, E219)."""
        if driver not in self._drivers:
            try:
                found = self.driver_lookup(driver)
            except Exception as exc:  # ModuleError, or a library that fails to import: said at the device
                self._driver_errors[driver] = str(exc)
                found = None
            self._drivers[driver] = found if isinstance(found, type) else None
        return self._drivers[driver]

    def driver_registered(self, name: str, driver: str, loc: Location) -> bool:
        """E219 unless `driver` names a registered driver: opening the device would fail in the task's init."""
        if self.driver_class(driver) is not None:
            return True
        reason = self._driver_errors.get(driver, "")
        if "failed to import" in reason:
            hint = reason
        else:
            try:
                hint = did_you_mean(driver, registry.names(registry.DRIVERS), "registered")
            except Exception:  # a broken registry must not hide the user's mistake
                hint = reason
        self.error("E219", f"device '{name}' uses driver '{driver}', which is not registered", loc, hint)
        return False

    def drivers_of_kind(self, kind: str) -> str:
        """'drivers of kind spp: spp' - the registered drivers a device of `kind` may use, for a hint."""
        try:
            names = [n for n in registry.names(registry.DRIVERS) if getattr(self.driver_class(n), "KIND", "") == kind]
        except Exception:  # a broken registry must not hide the user's mistake
            names = []
        return f"drivers of kind {kind}: {', '.join(names)}" if names else f"no registered driver is of kind {kind}"

    def plant_lacks(self, device: str) -> tuple[str, str] | None:
        """What a device (or the I/O device it is wired through) needs of the plant that the file
        does not give (its driver's NEEDS_PLANT, PLANT_OPTIONS), with a hint; None when nothing."""
        seen: set[str] = set()
        while device in self.out.devices and device not in seen:
            seen.add(device)
            spec = self.out.devices[device]
            cls = self.driver_class(spec.driver)
            if cls is not None and getattr(cls, "NEEDS_PLANT", False):
                plant = self.out.plant
                if plant is None:
                    if self.plant_written:
                        return None  # the plant is wrong, and was reported there
                    return (f"device '{device}' (driver {spec.driver}), hardware the plant simulates, but the file has no plant:",
                            "add a plant, e.g. plant: {model: puma560, timestep: 1 ms}")
                missing = [o for o in getattr(cls, "PLANT_OPTIONS", ()) if o not in plant.options]
                if missing:
                    return (
                        f"device '{device}' (driver {spec.driver}), which reads the plant's option {', '.join(missing)}, but "
                        "plant: does not give it",
                        f"give the plant {', '.join(missing)}: (docs/modules.md, 'Drivers', says what it takes)",
                    )
            if spec.io is None:
                return None
            device = spec.io.device
        return None

    def ports_of(self, device: str) -> int | None:
        """How many channels a device has (0: not port-based), or None when its driver is unknown."""
        spec = self.out.devices.get(device)
        cls = self.driver_class(spec.driver) if spec is not None else None
        if cls is None:
            return None
        ports = getattr(cls, "PORTS", 0)
        return ports if isinstance(ports, int) and ports >= 0 else 0

    def driver_accepts(self, name: str, driver: str, options: dict[str, Any], loc: Location, node: YMap | None = None) -> bool:
        """The driver's own check of the device's options (E607, at the option it names); True when it has none or they pass."""
        cls = self.driver_class(driver)
        check = getattr(cls, "check_options", None)
        if check is None:
            return True
        try:
            check(options)
        except (ValueError, TypeError) as exc:
            self.error(
                "E607",
                f"device '{name}' (driver {driver}): {exc}",
                (named_by(node, str(exc), DEVICE_KEYS) if node is not None else None) or loc,
                "the driver's docstring lists its options (docs/modules.md, 'Drivers')",
            )
            return False
        return True

    def port_claim(self, value: Any, loc: Location, what: str, owner: str, allow_name: bool) -> PortClaim | None:
        """A device name (if `allow_name`) or {device: name, channels: ...}, as a PortClaim; None (and errors) if wrong."""
        if allow_name and isinstance(value, str):
            return PortClaim(value, None, loc)
        example = "e.g. {device: adc0, channels: 0-5}"
        if not isinstance(value, YMap):
            expected = (
                "a device name or a mapping {device: ..., channels: ...}"
                if allow_name
                else "a mapping {device: ..., channels: ...}"
            )
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
                    self.error(
                        "E606",
                        f"device '{name}' (driver {spec.driver}) reads through a device of kind {wants}, but it has no io:",
                        spec.loc,
                        f"say where it is wired, e.g. io: {{device: <a device of kind {wants}>, channels: 0-5}}",
                    )
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
                    found = f"is of kind {kind}" if getattr(io_cls, "PORTS", 0) else "is not an I/O device"
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
