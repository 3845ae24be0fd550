"""The configuration checker: every rule of the format (docs/configuration.md, docs/error-codes.md), all
errors of a file in one pass.

It walks a loaded YAML document (`config.yaml_nodes.YMap`), reports each mistake like a compiler
(`file:line:col: error[E403]: ...` with the objects, what was found, the valid choices and a hint;
every rule has a stable code, listed in docs/error-codes.md),
and builds the frozen specs of `config.model` from what is right, so the loader can assemble a
`Subsystem` when nothing is wrong. It never stops at the first mistake: a broken part is left out
of the later rules so one typo does not cascade into a page of follow-on errors.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from pbo_runtime.config.checker.base import CheckerBase
from pbo_runtime.config.checker.claims import ClaimChecks
from pbo_runtime.config.checker.configurations import ConfigurationChecks
from pbo_runtime.config.checker.decisions import DecisionChecks
from pbo_runtime.config.checker.devices import DeviceChecks
from pbo_runtime.config.checker.inference import InferenceChecks
from pbo_runtime.config.checker.jobs import JobChecks
from pbo_runtime.config.checker.loops import JointLoopChecks
from pbo_runtime.config.checker.model import (
    BUS_KEYS,
    CLAIM_KEYS,
    DEVICE_KEYS,
    DTYPES,
    JOB_KEYS,
    RTPU_KEYS,
    TASK_KEYS,
    TOP_KEYS,
    TOP_REQUIRED,
    VARIABLE_KEYS,
    Checked,
    DriverLookup,
    ModuleLookup,
)
from pbo_runtime.config.checker.module_links import ModuleLinkChecks
from pbo_runtime.config.checker.objects import ObjectChecks
from pbo_runtime.config.checker.sections import SectionChecks
from pbo_runtime.config.checker.task_devices import TaskDeviceChecks
from pbo_runtime.config.checker.task_ports import TaskPortChecks
from pbo_runtime.config.checker.tasks import TaskChecks
from pbo_runtime.config.checker.timing import TimingChecks
from pbo_runtime.config.checker.variables import VariableChecks
from pbo_runtime.config.checker.words import describe, did_you_mean
from pbo_runtime.config.model import NOWHERE, Location

__all__ = [
    "BUS_KEYS",
    "CLAIM_KEYS",
    "DEVICE_KEYS",
    "DTYPES",
    "JOB_KEYS",
    "RTPU_KEYS",
    "TASK_KEYS",
    "TOP_KEYS",
    "VARIABLE_KEYS",
    "Checked",
    "DriverLookup",
    "ModuleLookup",
    "check_document",
    "describe",
    "did_you_mean",
]


class _Checker(
    SectionChecks,
    DeviceChecks,
    VariableChecks,
    InferenceChecks,
    TaskChecks,
    TaskPortChecks,
    TaskDeviceChecks,
    ConfigurationChecks,
    ClaimChecks,
    ModuleLinkChecks,
    ObjectChecks,
    JobChecks,
    DecisionChecks,
    TimingChecks,
    JointLoopChecks,
    CheckerBase,
):
    """The whole checker: the core (`CheckerBase`) with every rule, one mixin a concept, and the pass."""

    def run(self, doc: Any, doc_loc: Location) -> Checked:
        """Every rule over `doc`, in order; a broken part is left out of the rules after it."""
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
        self.check_tasks(top)  # also makes the variables no entry types, from their ports
        self.check_table_size(top)
        self.check_object_types(top)  # after the tasks: an object variable's type may come from its ports
        self.check_objects(top)
        self.check_configurations(top)
        self.check_jobs(top)
        self.check_applications(top)
        for config in self.config_members:
            self.check_data_flow(config)
        self.check_device_union()
        self.check_schedulability()
        self.check_spins()
        self.check_simulation_grid()
        self.check_const_order()
        self.check_joint_loops(top)
        self.check_unused()
        return self.out


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
