"""Application files: several subsystems run in parallel, joined by links (TR §5).

    application: two_arms
    hosts: {arm-a: 10.0.0.1, arm-b: 10.0.0.2}   # optional: the machines, by name, with their addresses
    subsystems:                     # name -> its subsystem file (relative to this file), or the subsystem inline
      leader: {config: leader.yaml, host: arm-a}  # placed on a host (or plain: `leader: leader.yaml`)
      follower: {config: follower.yaml, host: arm-b}
      operator: {host: arm-a, subsystem: operator, rtpus: [rtpu0], ...}  # inline: `host:` beside its keys
    links:                          # by name: periodic (triple buffers) or message (queues)
      arm_state: {type: float64, shape: [6], transport: zenoh, port: 7447}  # transport: shm | zenoh
      goal: {kind: message, type: float64, shape: [6], capacity: 4}
      wrist: {type: float64, shape: [6], transport: zenoh, endpoint: "tcp/192.168.1.20:7447"}
    run:                            # optional, per subsystem: its configuration or its application
      operator: {app: tour}

A link's ends are tasks of the subsystems, in two different subsystems, each with its port
`value` linked to a variable of the link's type and shape: a periodic link joins one
`link_sender` and one `link_receiver`; a message link one `message_sender` and one
`message_server` (an aperiodic task the message releases, TR §5.1). An inline subsystem is
loaded by every process as `app.yaml#key` (`config.loader.inline_reference`), so its errors
point into the application file. `check_application` checks the file like `pbo check` checks a
subsystem: every subsystem in full, then the links against the tasks, every mistake with
file:line:col, a code (E8xx, docs/error-codes.md) and a hint.

Placement: once one subsystem names a host, every one must, each host needs an address (in
`hosts:` or given with `--address HOST=ADDRESS`, `addresses` here), and a link between two hosts
must be `transport: zenoh`. A zenoh link's listening end (the periodic sender, the message server)
listens on its host's address at the link's `port:`, by default DEFAULT_LINK_PORT plus the link's
position among the file's zenoh links: both machines derive the same endpoint from the same file.
"""

from __future__ import annotations

import difflib
import os
import re
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pbo_runtime.config.loader import CheckResult, check_file, inline_reference
from pbo_runtime.config.model import NOWHERE, Location, Subsystem
from pbo_runtime.config.parallel import Error, check_stages
from pbo_runtime.config.yaml_nodes import YList, YMap, load_file, location_of
from pbo_runtime.errors import ConfigError
from pbo_runtime.links.spec import TRANSPORTS, parse_endpoint

SENDER, RECEIVER = "link_sender", "link_receiver"
MESSAGE_SENDER, SERVER = "message_sender", "message_server"
ENDS = {"periodic": (SENDER, RECEIVER), "message": (MESSAGE_SENDER, SERVER)}  # kind -> (sending, receiving) module
_KIND_OF_MODULE = {module: kind for kind, pair in ENDS.items() for module in pair}
_TOP_KEYS = ("application", "hosts", "subsystems", "links", "run")
_LINK_KEYS = ("kind", "type", "shape", "transport", "capacity", "endpoint", "port")
_PLACED_KEYS = ("config", "host")  # a subsystem entry that places a subsystem file on a host
DEFAULT_LINK_PORT = 7447  # a zenoh link without port: or endpoint: listens on this plus its position among the zenoh links
_ADDRESS = re.compile(r"^[A-Za-z0-9]([A-Za-z0-9.-]*[A-Za-z0-9])?$")  # a host name or an IPv4 address
_RUN_KEYS = ("config", "app")
MESSAGE_OVERHEAD_BYTES = 32  # msgpack framing, the time stamp and the relay's envelope
MSGPACK_BYTES_PER_NUMBER = 9  # a float64 or a large integer, encoded


@dataclass(frozen=True)
class LinkSpec:
    name: str
    dtype: str
    shape: tuple[int, ...]
    transport: str = "shm"
    sender: tuple[str, str] = ("", "")  # (subsystem, task)
    receiver: tuple[str, str] = ("", "")
    loc: Location = NOWHERE
    kind: str = "periodic"  # or "message"
    capacity: int = 0  # a message link's queue: messages it holds (0: the system's most)
    endpoint: str = ""  # zenoh: where the listening end listens, "tcp/<host>:<port>" ("": from its host and port)
    port: int = 0  # zenoh: the port its listening end listens on when placed on a host (given, or the default)
    port_given: bool = False  # `port:` was written: used on loopback too when the application runs on one machine


@dataclass
class Application:
    name: str
    file: str
    subsystems: dict[str, Subsystem] = field(default_factory=dict)  # by the application's name for it
    links: dict[str, LinkSpec] = field(default_factory=dict)
    run: dict[str, dict[str, str]] = field(default_factory=dict)  # subsystem -> {"config": ..., "app": ...}
    hosts: dict[str, str] = field(default_factory=dict)  # host name -> its address (the file's, or the command line's)
    placement: dict[str, str] = field(default_factory=dict)  # subsystem -> the host it runs on (absent: none named)
    entry_locs: dict[str, Location] = field(default_factory=dict)  # subsystem -> where the application file names it
    hosts_refused: bool = False  # hosts: was not a mapping (reported once: no error per host named)
    stages: list[dict[str, dict[str, Any]]] = field(default_factory=list)  # run: as parallel stages (config.parallel)

    def listening_subsystem(self, link: str) -> str:
        """The subsystem whose end of zenoh link `link` listens: the periodic sender, or the message server."""
        spec = self.links[link]
        return spec.sender[0] if spec.kind == "periodic" else spec.receiver[0]

    def on_host(self, host: str) -> list[str]:
        """The subsystems placed on `host`, in file order."""
        return [key for key in self.subsystems if self.placement.get(key) == host]


@dataclass
class ApplicationCheck:
    application: Application | None
    errors: list[ConfigError] = field(default_factory=list)
    warnings: list[ConfigError] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.errors


def check_application(path: str | os.PathLike[str], addresses: Mapping[str, str] | None = None) -> ApplicationCheck:
    """Every problem of an application file and of its subsystems' files; never raises on bad input.

    `addresses`: host name -> address given on the command line (`--address`), over the file's.
    """
    file = str(path)
    result = ApplicationCheck(None)
    try:
        root = load_file(file)
    except ConfigError as exc:
        result.errors.append(exc)
        return result

    def error(code: str, message: str, loc: Location, hint: str = "") -> None:
        result.errors.append(ConfigError(message, loc.file, loc.line, loc.column, hint, code=code))

    if not isinstance(root, YMap):
        error("E801", "an application file must be a mapping with application, subsystems and links",
              location_of(root, Location(file, 1, 1)))
        return result
    for key in root:
        if key not in _TOP_KEYS:
            error("E801", f"unknown key '{key}' in an application file", root.key_loc(key),
                  f"an application file has: {', '.join(_TOP_KEYS)}")
    name = root.get("application")
    if not isinstance(name, str) or not name:
        error("E801", "application must be a name", root.value_loc("application") if "application" in root else root.loc,
              "e.g. application: two_arms")
        name = "application"
    application = Application(name, file)
    _check_hosts(root, application, dict(addresses or {}), error)
    _check_subsystems(root, Path(file).parent, application, result, error)
    _check_links(root, application, error)
    _check_run(root, application, error)
    if not result.errors:
        _check_link_ends(application, error)
    if not result.errors:
        _check_placement(application, error)
    if not result.errors:
        result.application = application
    return result


def _check_subsystems(root: YMap, folder: Path, application: Application, result: ApplicationCheck, error: Error) -> None:
    entries = root.get("subsystems")
    if not isinstance(entries, YMap) or not entries:
        error("E801", "subsystems must map each subsystem's name to its file",
              root.value_loc("subsystems") if "subsystems" in root else root.loc, "e.g. subsystems: {leader: leader.yaml}")
        return
    names: dict[str, str] = {}
    for key, value in entries.items():
        loc = entries.value_loc(key)
        application.entry_locs[key] = entries.key_loc(key)
        if isinstance(value, YMap) and "config" in value and "subsystem" not in value:  # {config: FILE, host: HOST}
            unknown = [k for k in value if k not in _PLACED_KEYS]
            if unknown:
                error("E802", f"subsystem '{key}': unknown key '{unknown[0]}'", value.key_loc(unknown[0]),
                      f"a placed subsystem has: {', '.join(_PLACED_KEYS)} (e.g. {{config: leader.yaml, host: arm-a}})")
                continue
            _place(key, value, application, error)
            loc, value = value.value_loc("config"), value["config"]
        elif isinstance(value, YMap) and "host" in value:  # inline, placed: `host:` beside the subsystem's keys
            _place(key, value, application, error)
        if isinstance(value, YMap):
            path: Path | str = inline_reference(application.file, key)
        elif not isinstance(value, str):
            error("E802", f"subsystem '{key}' must be the path of its subsystem file, or the subsystem itself", loc,
                  "e.g. leader: leader.yaml, or operator: {subsystem: operator, rtpus: [rtpu0], ...}")
            continue
        else:
            path = folder / value
            if not path.is_file():
                error("E802", f"subsystem '{key}': no file '{value}' (looked for {path})", loc,
                      "paths are relative to the application file")
                continue
        checked: CheckResult = check_file(path)
        result.errors.extend(checked.errors)
        result.warnings.extend(checked.warnings)
        if checked.subsystem is None:
            if not checked.errors:
                error("E802", f"subsystem '{key}': '{path}' could not be loaded", loc)
            continue
        own = checked.subsystem.name
        if own in names:
            error("E802", f"subsystems '{names[own]}' and '{key}' are both named '{own}' in their files", loc,
                  "each subsystem's `subsystem:` name must be unique: it names its shared memory")
            continue
        names[own] = key
        application.subsystems[key] = checked.subsystem


def _check_hosts(root: YMap, application: Application, addresses: dict[str, str], error: Error) -> None:
    """`hosts: {name: ADDRESS}`; an address may be left empty (~) and given on the command line."""
    entries = root.get("hosts", YMap(root.loc))
    if not isinstance(entries, YMap):
        error("E809", "hosts must map each host's name to its address", location_of(entries, root.loc),
              "e.g. hosts: {arm-a: 10.0.0.1, arm-b: 10.0.0.2}")
        application.hosts_refused = True
        return
    for name, address in entries.items():
        loc = entries.value_loc(name)
        if address is None or address == "":
            application.hosts[name] = ""
            continue
        if not isinstance(address, str) or not _ADDRESS.match(address):
            error("E809", f"host '{name}': address must be a host name or an IPv4 address, got {address!r}", loc,
                  "e.g. arm-a: 10.0.0.1 (or leave it empty, ~, and give it with --address arm-a=10.0.0.1)")
            application.hosts[name] = str(address)  # reported: its subsystems are not told again
            continue
        application.hosts[name] = address
    for name, address in addresses.items():
        if name not in application.hosts:
            error("E809", f"--address names host '{name}', which the application does not declare",
                  root.key_loc("hosts") if "hosts" in root else root.loc, did_you_mean(name, application.hosts, "hosts"))
            continue
        if not _ADDRESS.match(address):
            error("E809", f"--address {name}={address}: the address must be a host name or an IPv4 address",
                  root.key_loc("hosts"), f"e.g. --address {name}=10.0.0.2")
            continue
        application.hosts[name] = address


def did_you_mean(name: str, known: Collection[str], what: str) -> str:
    close = difflib.get_close_matches(name, list(known), n=1)
    if close:
        return f"did you mean '{close[0]}'? ({what}: {', '.join(known)})"
    return f"{what}: {', '.join(known) or 'none'}"


def _place(key: str, entry: YMap, application: Application, error: Error) -> None:
    """Subsystem `key`'s `host:`: a host of `hosts:` with an address."""
    host = entry["host"]
    loc = entry.value_loc("host")
    if application.hosts_refused:
        application.placement[key] = str(host)
        return
    if not isinstance(host, str) or not host:
        error("E810", f"subsystem '{key}': host must name a host of hosts:, got {host!r}", loc, "e.g. host: arm-a")
        return
    if host not in application.hosts:
        error("E810", f"subsystem '{key}' is placed on host '{host}', which hosts: does not declare", loc,
              did_you_mean(host, application.hosts, "hosts") + "; declare it under hosts: {NAME: ADDRESS}")
        return
    if not application.hosts[host]:
        error("E810", f"host '{host}' of subsystem '{key}' has no address", loc,
              f"give it in the file (hosts: {{{host}: 10.0.0.2}}) or on the command line: --address {host}=10.0.0.2")
        return
    application.placement[key] = host


def _check_links(root: YMap, application: Application, error: Error) -> None:
    entries = root.get("links", YMap(root.loc))
    if not isinstance(entries, YMap):
        error("E803", "links must map each link's name to its kind, type, shape and transport", location_of(entries, root.loc))
        return
    for name, spec in entries.items():
        loc = entries.key_loc(name)
        if not isinstance(spec, YMap):
            error("E803", f"link '{name}' must be a mapping", entries.value_loc(name), "e.g. {type: float64, shape: [6]}")
            continue
        for key in spec:
            if key not in _LINK_KEYS:
                error("E803", f"link '{name}': unknown key '{key}'", spec.key_loc(key), f"a link has: {', '.join(_LINK_KEYS)}")
        kind = spec.get("kind", "periodic")
        if kind not in ENDS:
            error("E803", f"link '{name}': unknown kind '{kind}'", spec.value_loc("kind"),
                  "kind: periodic (a triple buffer: the newest item, every cycle) or kind: message (a queue: every item, once)")
            continue
        dtype = spec.get("type", "float64")
        try:
            np.dtype(dtype)
        except TypeError:
            error("E803", f"link '{name}': type '{dtype}' is not a numpy dtype", spec.value_loc("type"), "e.g. float64, int32")
            continue
        shape = spec.get("shape", YList(loc))
        if not isinstance(shape, list) or not all(isinstance(n, int) and n > 0 for n in shape):
            error("E803", f"link '{name}': shape must be a list of positive integers, got {shape!r}",
                  spec.value_loc("shape") if "shape" in spec else loc, "e.g. shape: [6]")
            continue
        transport = spec.get("transport", "shm")
        if transport not in TRANSPORTS:
            error("E803", f"link '{name}': unknown transport '{transport}'", spec.value_loc("transport"),
                  f"transports: {', '.join(TRANSPORTS)}")
            continue
        capacity = _message_capacity(name, kind, spec, shape, error)
        if capacity is None:
            continue
        endpoint = spec.get("endpoint", "")
        if endpoint and transport != "zenoh":
            error("E803", f"link '{name}' uses transport '{transport}', which takes no endpoint", spec.key_loc("endpoint"),
                  "an endpoint is where a zenoh link listens: add transport: zenoh, or remove it")
            continue
        if endpoint and parse_endpoint(endpoint) is None:
            error("E803", f"link '{name}': endpoint must be tcp/<host>:<port>, got {endpoint!r}", spec.value_loc("endpoint"),
                  "e.g. endpoint: tcp/192.168.1.20:7447 (the address of the machine whose subsystem listens)")
            continue
        port = spec.get("port", 0)
        if "port" in spec and (transport != "zenoh" or endpoint):
            error(
                "E812",
                f"link '{name}' takes no port: " + ("its endpoint names one" if endpoint else f"its transport is {transport}"),
                spec.key_loc("port"),
                "a port is where a zenoh link's listening end listens on its host; "
                "give either port: or endpoint:, and only with transport: zenoh",
            )
            continue
        if "port" in spec and (not isinstance(port, int) or isinstance(port, bool) or not 0 < port < 65536):
            error("E812", f"link '{name}': port must be a TCP port from 1 to 65535, got {port!r}", spec.value_loc("port"),
                  f"e.g. port: {DEFAULT_LINK_PORT}")
            continue
        application.links[name] = LinkSpec(name, str(np.dtype(dtype)), tuple(shape), transport, loc=loc, kind=kind,
                                           capacity=capacity, endpoint=str(endpoint), port=port, port_given="port" in spec)


def _message_capacity(name: str, kind: str, spec: YMap, shape: list[int], error: Error) -> int | None:
    """A message link's capacity (default: the system's most), checked; None after an error."""
    if kind != "message":
        if "capacity" in spec:
            error("E803", f"link '{name}' is periodic and takes no capacity", spec.key_loc("capacity"),
                  "a triple buffer holds the newest item only; capacity is for kind: message")
            return None
        return 0
    from pbo_runtime.links.message_link import (  # the machine's queues: read for message links only
        SYSTEM_CAPACITY,
        SYSTEM_MESSAGE_BYTES,
    )

    capacity = spec.get("capacity", SYSTEM_CAPACITY)
    if not isinstance(capacity, int) or isinstance(capacity, bool) or not 1 <= capacity <= SYSTEM_CAPACITY:
        error("E803", f"link '{name}': capacity must be a whole number of messages from 1 to {SYSTEM_CAPACITY}, "
                      f"got {capacity!r}", spec.value_loc("capacity"),
              f"this machine's queues hold at most fs.mqueue.msg_max = {SYSTEM_CAPACITY} messages")
        return None
    encoded = MSGPACK_BYTES_PER_NUMBER * int(np.prod(shape)) + MESSAGE_OVERHEAD_BYTES
    if encoded > SYSTEM_MESSAGE_BYTES:
        error("E803", f"link '{name}': a message of {list(shape)} numbers takes about {encoded} bytes, more than "
                      f"the {SYSTEM_MESSAGE_BYTES} a message may hold", spec.value_loc("shape") if "shape" in spec else spec.loc,
              "send bulk data through a periodic link (kind: periodic), and commands or goals as messages")
        return None
    return capacity


def _check_run(root: YMap, application: Application, error: Error) -> None:
    """`run: {subsystem: {config: NAME} | {app: NAME}}`: what each subsystem runs (default: its first configuration)."""
    entries = root.get("run", YMap(root.loc))
    if isinstance(entries, YList):  # stages: parallel: {SUBSYSTEM: STEPS, ...}, one after another
        application.stages = check_stages(entries, application.subsystems, bool(application.placement), error, did_you_mean)
        return
    if not isinstance(entries, YMap):
        error("E807", "run must map subsystems to {config: NAME} or {app: NAME}", location_of(entries, root.loc),
              "e.g. run: {operator: {app: tour}}")
        return
    for key, options in entries.items():
        if key not in application.subsystems:
            if key not in (root.get("subsystems") or {}):
                error("E807", f"run: no subsystem '{key}' in this application", entries.key_loc(key),
                      f"subsystems: {', '.join(application.subsystems) or 'none'}")
            continue
        if not isinstance(options, YMap) or not options:
            error("E807", f"run: subsystem '{key}' needs {{config: NAME}} or {{app: NAME}}", entries.value_loc(key))
            continue
        subsystem = application.subsystems[key]
        chosen: dict[str, str] = {}
        for option, value in options.items():
            if option not in _RUN_KEYS:
                error("E807", f"run: unknown option '{option}' for subsystem '{key}'", options.key_loc(option),
                      "config: a configuration to turn on, or app: an application of the subsystem's jobs")
                continue
            known = subsystem.configurations if option == "config" else subsystem.applications
            if value not in known:
                what = "configuration" if option == "config" else "application"
                error("E807", f"run: subsystem '{key}' has no {what} '{value}'", options.value_loc(option),
                      f"its {what}s: {', '.join(known) or 'none'}")
                continue
            if option == "app" and not subsystem.applications[value].complete:
                complete = [name for name, app in subsystem.applications.items() if app.complete]
                error("E807", f"run: application '{value}' of subsystem '{key}' is incomplete (a step lacks the object its "
                              "job needs): an incomplete application cannot be run", options.value_loc(option),
                      f"run a complete application ({', '.join(complete) or 'the subsystem has none'}), or give the step its "
                      f"object; pbo check {subsystem.file} shows which step")
                continue
            chosen[option] = value
        if len(chosen) == 2:
            error("E807", f"run: subsystem '{key}' takes a configuration or an application, not both",
                  entries.key_loc(key), "an application's jobs choose their own configurations")
            continue
        application.run[key] = chosen


def _check_link_ends(application: Application, error: Error) -> None:
    """Each link: one sending and one receiving task of its kind, in different subsystems, ports of its payload."""
    ends: dict[str, dict[str, list[tuple[str, str, Location]]]] = {
        n: {module: [] for module in ENDS[spec.kind]} for n, spec in application.links.items()}
    refused: set[tuple[str, str]] = set()  # (link, module) of ends already reported: no "has no ..." on top
    for key, subsystem in application.subsystems.items():
        for task in subsystem.tasks.values():
            kind = _KIND_OF_MODULE.get(task.module)
            if kind is None:
                continue
            link = task.params.get("link")
            if link not in application.links:
                error(
                    "E804",
                    f"task '{task.name}' of subsystem '{key}' uses link '{link}', which the application does not declare",
                    task.loc,
                    f"links: {', '.join(application.links) or 'none'}; declare it under links:",
                )
                continue
            spec = application.links[link]
            if spec.kind != kind:
                refused.update((link, module) for module in ENDS[spec.kind])
                fitting = " and ".join(ENDS[spec.kind])
                error("E808", f"task '{task.name}' of subsystem '{key}' is a {task.module}, a {kind} link's end, but "
                              f"link '{link}' is a {spec.kind} link", task.loc,
                      f"a {spec.kind} link's ends are {fitting}; or declare the link with kind: {kind}")
                continue
            if task.module == SERVER and not task.aperiodic:
                refused.add((link, task.module))
                error("E808", f"task '{task.name}' of subsystem '{key}' serves message link '{link}' but is periodic",
                      task.loc, "a message_server runs when a message arrives: give it aperiodic: true and a "
                                "min_interarrival: (e.g. 10 ms) instead of a period")
                continue
            binding = next(b for b in task.bindings if b.port.name == "value")
            variable = subsystem.variables[binding.variable]
            if (np.dtype(variable.dtype), tuple(variable.shape)) != (np.dtype(spec.dtype), spec.shape):
                refused.add((link, task.module))
                error("E806", f"task '{task.name}' of subsystem '{key}' links variable '{variable.name}' "
                              f"({variable.dtype} {list(variable.shape)}) to link '{link}', which carries "
                              f"{spec.dtype} {list(spec.shape)}", task.loc,
                      "the variable and the link must have the same type and shape")
                continue
            ends[link][task.module].append((key, task.name, task.loc))
    for name, spec in application.links.items():
        sending, receiving = ENDS[spec.kind]
        senders, receivers = ends[name][sending], ends[name][receiving]
        for role, found in ((sending, senders), (receiving, receivers)):
            if not found and (name, role) not in refused:
                extra_keys = ", aperiodic: true, min_interarrival: 10 ms" if role == SERVER else ""
                error("E805", f"link '{name}' has no {role} task", spec.loc,
                      f"add a task with module: {role}, params: {{link: {name}}}{extra_keys} to one subsystem")
            for extra in found[1:]:
                error("E805", f"link '{name}' has a second {role}: task '{extra[1]}' of subsystem '{extra[0]}' "
                              f"(the first is '{found[0][1]}' of '{found[0][0]}')", extra[2],
                      "a link joins one sender and one receiver")
        if senders and receivers and senders[0][0] == receivers[0][0]:
            error("E805", f"link '{name}' joins two tasks of the same subsystem '{senders[0][0]}'", spec.loc,
                  "within a subsystem, tasks share state variables: use a variable, not a link")
        if senders and receivers:
            application.links[name] = LinkSpec(name, spec.dtype, spec.shape, spec.transport, senders[0][:2],
                                               receivers[0][:2], spec.loc, spec.kind, spec.capacity, spec.endpoint,
                                               spec.port, spec.port_given)


def _check_placement(application: Application, error: Error) -> None:
    """Every subsystem on a host once one is; links between hosts over zenoh; one listener per host and port."""
    placed = [key for key in application.subsystems if application.placement.get(key)]
    if placed:
        for key in application.subsystems:
            if key not in application.placement:
                error(
                    "E810",
                    f"subsystem '{key}' names no host, while '{placed[0]}' is placed on '{application.placement[placed[0]]}'",
                    application.entry_locs.get(key, NOWHERE),
                    f"place every subsystem: {key}: {{config: FILE, host: HOST}} (inline: host: HOST beside its keys)",
                )
        if any(key not in application.placement for key in application.subsystems):
            return
    listeners: dict[tuple[str, int], str] = {}
    zenoh_links = [name for name, spec in application.links.items() if spec.transport == "zenoh"]
    for name, spec in list(application.links.items()):
        ends = (application.placement.get(spec.sender[0], ""), application.placement.get(spec.receiver[0], ""))
        if spec.transport != "zenoh":
            if ends[0] != ends[1]:
                error("E811", f"link '{name}' joins {spec.sender[0]} on host '{ends[0]}' and {spec.receiver[0]} on host "
                              f"'{ends[1]}', but its transport is {spec.transport}", spec.loc,
                      "shared memory stays on one machine: give the link transport: zenoh")
            continue
        port = spec.port or DEFAULT_LINK_PORT + zenoh_links.index(name)
        application.links[name] = LinkSpec(name, spec.dtype, spec.shape, spec.transport, spec.sender, spec.receiver,
                                           spec.loc, spec.kind, spec.capacity, spec.endpoint, port, spec.port_given)
        if spec.endpoint or not placed:
            continue
        listening = application.placement[application.listening_subsystem(name)]
        other = listeners.setdefault((listening, port), name)
        if other != name:
            error("E812", f"links '{other}' and '{name}' would both listen on host '{listening}' at port {port}", spec.loc,
                  f"give one of them another port: (links without one take {DEFAULT_LINK_PORT} plus their position "
                  "among the zenoh links)")
