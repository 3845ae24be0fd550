"""Join connector (TR Figure 6): one unambiguous output from several conflicting ones.

When two modules would write the same variable, each writes its own intermediate variable
instead (p', p''), and the join connector combines them into p. Its inputs are the variables
named in `params.inputs`; its output port `out` is linked to the joined variable with
`ports: {out: p}`. The combining operation (`combine`):

    average (default)   p = Σ w_i x_i / Σ w_i   a weighted average, e.g. blending two references
    sum                 p = Σ w_i x_i           a weighted sum, e.g. feedback torque + gravity torque
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pbo_runtime import ANY_DTYPE, InVar, ModuleError, OutVar, PortBasedObject, PortSpec, Status, param


@dataclass(frozen=True)
class JoinParams:
    inputs: tuple[str, ...]
    weights: tuple[float, ...] = param((), at_least=0, at_most=1e6)  # default: equal weights
    combine: str = "average"  # or "sum": the weights are not normalised

    def __post_init__(self) -> None:
        if self.combine not in ("average", "sum"):
            raise ValueError(f"combine must be 'average' or 'sum', got: {self.combine!r}")
        if len(self.inputs) < 2:
            raise ValueError(f"inputs must name at least two variables to join, got: {list(self.inputs)}")
        if len(set(self.inputs)) != len(self.inputs):
            raise ValueError(f"inputs must not repeat, got: {list(self.inputs)}")
        if self.weights and len(self.weights) != len(self.inputs):
            raise ValueError(
                f"weights and inputs must have equal length: |weights| = {len(self.weights)}, |inputs| = {len(self.inputs)}"
            )
        if self.weights and (any(w < 0 for w in self.weights) or sum(self.weights) <= 0):
            raise ValueError(f"weights must be >= 0 and not all zero, got: {list(self.weights)}")


class Join(PortBasedObject):
    """Weighted average (or sum) of its inputs: out = Σ w_i x_i / Σ w_i. Real-time safe cycle."""

    Params = JoinParams

    out = OutVar("joined", dtype=ANY_DTYPE, shape=None, doc="the joined variable (link it with ports: {out: <variable>})")

    @classmethod
    def ports_for(cls, params: JoinParams) -> tuple[PortSpec, ...]:
        inputs = tuple(
            PortSpec(name, InVar.kind, name, ANY_DTYPE, None, f"input {i} of the join") for i, name in enumerate(params.inputs)
        )
        return cls.ports() + inputs

    @classmethod
    def same_shape(cls, params: JoinParams) -> tuple[tuple[str, ...], ...]:
        return (("out", *params.inputs),)  # pbo check refuses inputs of another shape than the output

    def init(self, params: JoinParams) -> None:
        self._inputs = self.bound_arrays[1:]
        for name, array in zip(params.inputs, self._inputs, strict=True):
            if array.shape != self.out.shape:
                raise ModuleError(f"join input '{name}' has shape {array.shape}, but the output has shape {self.out.shape}")
        weights = np.asarray(params.weights or [1.0] * len(params.inputs), dtype=float)
        if params.combine == "average":
            weights = weights / weights.sum()
        self._weights = tuple(float(w) for w in weights)
        self._term = np.zeros(self.out.shape, dtype=self.out.dtype)

    def cycle(self) -> Status:
        out, term = self.out, self._term
        out.fill(0)
        for weight, source in zip(self._weights, self._inputs):  # noqa: B905 - the cycle: equal by init, no check per cycle
            np.multiply(source, weight, out=term, casting="unsafe")
            np.add(out, term, out=out, casting="unsafe")
        return Status.CONTINUE
