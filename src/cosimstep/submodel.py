"""The black-box sub-model interface (thesis 3.2 and 4.1), shaped after FMI co-simulation.

A sub-model declares its input and output ports, accepts input values (and, when it can, their
time derivatives) before a step, advances itself from ``t`` to ``t + h`` with its own internal
solver, and exposes its outputs afterwards. It can optionally save and restore its complete state
so that a step can be re-run from the same initial condition (thesis 4.2.4.2; FMI's
``fmi2GetFMUstate``/``fmi2SetFMUstate``), and optionally report the time derivatives of its
outputs ("grey box", thesis 4.3.4).

Values cross this interface as NumPy arrays ordered like the declared ports, the way FMI uses
value references: the master sits in a hot loop and should not build dictionaries per call.
"""

from __future__ import annotations

import math
import pickle
import re
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

ELEMENT = re.compile(r"^(.+)\[\s*(\d+(?:\s*,\s*\d+)*)\s*\]$")
"""An array element's name, ``A[2,1]`` or ``y[3]``: the array's name and the 1-based indices."""


@dataclass(frozen=True)
class Port:
    """A named scalar input or output.

    ``start`` is the value an input takes when nothing is connected to it, and the value an output
    has before the first step. ``None`` means "no start value": an unconnected input without a
    start value is a configuration error.

    ``discrete`` marks a piecewise-constant output (a count, a switch, an impulse delivered so
    far): its receivers hold it over a step, it is never extrapolated or interpolated, and a
    change of it inside a step is an *event* the synchronous master locates by rollback
    (:mod:`cosimstep.loops`), as it locates a threshold crossing.
    """

    name: str
    unit: str = "1"
    start: float | None = None
    description: str = ""
    discrete: bool = False
    kind: str = "real"
    """What the value is: ``"real"``, ``"integer"`` (FMI Integer, Enumeration),
    ``"boolean"`` (0 or 1), ``"string"`` or ``"binary"`` (FMI String, Binary: the float is a
    code, :mod:`cosimstep.symbols`). Every value travels as a float (exact for integers up to
    2^53); the kind says what a receiver may be given: an integer or boolean input takes only an
    output of its own kind (or an integer into a boolean), unless the connection rounds; a
    string or binary input only an output of its own kind, unscaled."""


@dataclass(frozen=True)
class Capabilities:
    """What the master may ask of a sub-model.

    Attributes
    ----------
    can_save_state:
        ``save_state``/``restore_state`` work, so a step can be rejected and re-run.
    provides_derivatives:
        ``get_output_derivatives`` returns the time derivatives of the outputs (grey box).
    max_input_derivative_order:
        Highest order of input time derivative the sub-model uses during a step (0: inputs are
        held constant over the step, as in plain FMI ``doStep``; 2: the sub-model follows a
        quadratic input polynomial, like FMI's ``setRealInputDerivatives``).
    feedthrough:
        For each output with direct feedthrough, the inputs it depends on *at the same instant*.
        These are the edges that can form algebraic loops.
    max_step:
        Largest communication step the sub-model accepts.
    """

    can_save_state: bool = False
    provides_derivatives: bool = False
    max_input_derivative_order: int = 0
    feedthrough: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    max_step: float = math.inf

    @property
    def has_direct_feedthrough(self) -> bool:
        return any(self.feedthrough.values())


class SubModel(ABC):
    """Base class of every sub-model; subclass it to write a sub-model in Python.

    The master drives a sub-model in this order::

        initialize(t0)
        repeat:
            set_inputs(u); [set_input_derivatives(du)]; do_step(t, h); y = get_outputs()
            (optionally save_state() before and restore_state() to re-run a step)
        terminate()

    ``do_step`` must raise an exception when the sub-model cannot complete the step; the master
    turns it into a failed run that keeps the results so far. Returning NaN is caught too.
    """

    inputs: tuple[Port, ...] = ()
    outputs: tuple[Port, ...] = ()
    capabilities: Capabilities = Capabilities()

    def initialize(self, t0: float) -> None:  # noqa: B027 - optional hook
        """Prepare for a run starting at ``t0`` (set start values, allocate solvers)."""

    @abstractmethod
    def set_inputs(self, values: np.ndarray) -> None:
        """Set all inputs, ordered as :attr:`inputs`, valid from the current time on."""

    def set_input_derivatives(self, derivatives: np.ndarray) -> None:
        """Set input time derivatives, shape ``(order, n_inputs)``; row ``k`` is the ``k+1``-th.

        Only called when ``capabilities.max_input_derivative_order > 0``.
        """
        raise NotImplementedError(f"{type(self).__name__} does not accept input derivatives")

    @abstractmethod
    def do_step(self, t: float, h: float) -> None:
        """Advance the sub-model from ``t`` to ``t + h``."""

    @abstractmethod
    def get_outputs(self) -> np.ndarray:
        """Current outputs, ordered as :attr:`outputs`."""

    def get_output_derivatives(self) -> np.ndarray:
        """Time derivatives of the outputs at the current time (grey box, thesis 4.3.4)."""
        raise NotImplementedError(f"{type(self).__name__} does not provide output derivatives")

    def save_state(self) -> Any:
        """Return an opaque token holding the complete state (time, states, parameters)."""
        raise NotImplementedError(f"{type(self).__name__} cannot save its state")

    def restore_state(self, token: Any) -> None:
        """Return to a state previously returned by :meth:`save_state`."""
        raise NotImplementedError(f"{type(self).__name__} cannot restore its state")

    def serialize_state(self, token: Any) -> bytes:
        """Bytes of a state :meth:`save_state` returned, for a checkpoint another process can
        resume from (``cosimstep run --resume``). By default the token pickled: override this
        and :meth:`deserialize_state` when it holds something pickle cannot carry (a handle,
        a pointer), or raise ``NotImplementedError`` saying why the state cannot leave the
        process."""
        return pickle.dumps(token, protocol=pickle.HIGHEST_PROTOCOL)

    def deserialize_state(self, data: bytes) -> Any:
        """A token :meth:`restore_state` takes, from :meth:`serialize_state`'s bytes; called
        after :meth:`initialize` in the resuming process."""
        return pickle.loads(data)

    def time_events(self) -> Sequence[float]:
        """Times at which the sub-model changes abruptly; the master lands steps on them."""
        return ()

    def terminate(self) -> None:  # noqa: B027 - optional hook
        """Release resources; called once at the end of a run, also after a failure."""

    # Convenience for users and the master -------------------------------------------------
    def input_index(self, name: str) -> int:
        return _index(self.inputs, name, "input", type(self).__name__)

    def output_index(self, name: str) -> int:
        return _index(self.outputs, name, "output", type(self).__name__)


def _index(ports: Sequence[Port], name: str, kind: str, owner: str) -> int:
    for i, port in enumerate(ports):
        if port.name == name:
            return i
    known = ", ".join(p.name for p in ports) or "none"
    raise KeyError(f"{owner} has no {kind} '{name}' (its {kind}s: {known})")
