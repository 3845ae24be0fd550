"""Who holds which device (TR §4.6.1): the devices and channels a task opens, and where two tasks
want them at once, within a configuration or across the tasks a dynamic run spawns.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pbo_runtime.config.channels import format_channels
from pbo_runtime.config.checker.base import CheckerBase
from pbo_runtime.config.checker.model import _Claim, _Task
from pbo_runtime.config.checker.words import _and_list


class ClaimChecks(CheckerBase):
    """Rules for exclusive devices and channels: one user each."""

    if TYPE_CHECKING:  # rules of other mixins this one calls; the whole checker has them
        def ports_of(self, device: str) -> int | None: ...

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
                    f"device '{device}' is exclusive, but configuration '{config}' gives it to "
                    f"{_and_list([u.who() for u in us])}",
                    us[1].loc,
                    "an exclusive device has one user per configuration; move one task to another configuration, "
                    "or set exclusive: false if the driver can be shared",
                    [(u.loc, f"task '{u.task}' opens it here") for u in us if u is not us[1]],
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
                        [(earlier.loc, f"task '{earlier.task}' claims channels {format_channels(earlier.channels or ())} here")],
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
                        [(a.loc, f"task '{a.task}' opens it here")],
                    )
                    break


def _disjoint_hint(holder: _Claim, claimant: _Claim) -> str:
    """How to give `claimant` channels `holder` does not hold."""
    free = sorted(set(claimant.channels or ()) - set(holder.channels or ()))
    hint = "a channel has one user per configuration: give the tasks disjoint channels"
    if not free or claimant.via:
        return hint
    shown = format_channels(free)
    value = shown if ", " not in shown else f"[{shown}]"
    return f"{hint}, e.g. for '{claimant.task}': {{device: {claimant.device}, channels: {value}}}"
