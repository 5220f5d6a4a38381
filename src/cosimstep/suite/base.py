"""What a benchmark problem is, and the small helpers the problem modules share."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from cosimstep.adapters.ode import RK4, OdeSubModel
from cosimstep.reference import Reference
from cosimstep.submodel import Port
from cosimstep.system import System


@dataclass(frozen=True)
class Problem:
    """One coupled benchmark problem: a split system plus its monolithic reference.

    ``build()`` returns a *fresh* ``(system, reference)`` pair on every call (sub-models hold
    state, so two runs never share one). ``quick_until`` is a shorter horizon for fast tests.
    """

    name: str
    title: str
    classes: tuple[str, ...]
    source: str
    until: float
    build: Callable[[], tuple[System, Reference]]
    quick_until: float


class UnannouncedEvents(OdeSubModel):
    """An :class:`OdeSubModel` that integrates its own discontinuities but never announces them.

    This is what "unannounced" means in this suite: inside a communication step the sub-model
    still integrates piecewise across its jumps (:meth:`breakpoints` lists them, so its own
    result stays exact), but :meth:`time_events` returns ``()`` — the master is not told, does
    not land on the jump and has to notice it from the exchanged values alone, like a black box
    whose author forgot to declare the event. The monolithic reference is unaffected (it uses
    ``breakpoints``).
    """

    def time_events(self) -> Sequence[float]:
        return ()

    def breakpoints(self, t0: float, t1: float) -> list[float]:
        return [t for t in super().time_events() if t0 < t < t1]


def ports(spec: Mapping[str, tuple[str, float]], describe: Mapping[str, str] | None = None
          ) -> list[Port]:
    """``{"x": ("m", 0.1)}`` → ``[Port("x", "m", 0.1)]`` in the mapping's order."""
    describe = describe or {}
    return [Port(n, unit, float(start), describe.get(n, "")) for n, (unit, start) in spec.items()]


def connect_both_ways(system: System, a: str, b: str, a_to_b: Mapping[str, str],
                      b_to_a: Mapping[str, str]) -> System:
    """Connect ``a.out → b.in`` for every pair in ``a_to_b`` and ``b.out → a.in`` likewise."""
    for out, inp in a_to_b.items():
        system.connect(f"{a}.{out}", f"{b}.{inp}")
    for out, inp in b_to_a.items():
        system.connect(f"{b}.{out}", f"{a}.{inp}")
    return system


def scalar_pair(fx: Callable, fy: Callable, whole: Callable, start: tuple[float, float],
                names: tuple[str, str], events: Sequence[float] = ()
                ) -> tuple[System, Reference]:
    """Two one-state sub-models with fixed-step RK4 inside (what is measured is the coupling's
    error, not the internal solver's): ``a`` integrates state ``names[0]`` and reads the
    other, ``b`` the other way; ``whole`` is the monolithic right-hand side of both, the
    reference. ``events``: time events of ``fx`` (and so of ``whole``), announced by ``a``."""
    x, y = names
    a = OdeSubModel(fx, ports({x: ("1", start[0])}), inputs=ports({y: ("1", start[1])}),
                    solver=RK4(max_dt=1e-3), time_events=events)
    b = OdeSubModel(fy, ports({y: ("1", start[1])}), inputs=ports({x: ("1", start[0])}),
                    solver=RK4(max_dt=1e-3))
    system = connect_both_ways(System().add("a", a).add("b", b), "a", "b", {x: x}, {y: y})
    mono = OdeSubModel(whole, ports({x: ("1", start[0]), y: ("1", start[1])}),
                       time_events=events)
    return system, Reference(mono, {f"a.{x}": x, f"b.{y}": y})
