"""Step-size controllers: they decide the communication step ΔT (thesis 4.2).

A controller receives a :class:`StepContext` (which runs coupled steps, saves and restores the
sub-models, and exposes the stored history) and makes one *attempt* at ``[t, t + h]``: it runs
whatever calls it needs, decides whether the result is accepted, and proposes the next step. The
orchestrator owns the loop, time events, storage and failure handling, so a new controller is a
small class registered by name.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np


@dataclass
class Attempt:
    """Outcome of one attempt at a communication step."""

    y: np.ndarray
    accepted: bool
    h_next: float
    error: float | None = None


class StepContext(Protocol):
    """What a controller may use during an attempt."""

    times: list[float]
    history: np.ndarray

    def step(self, t: float, h: float) -> np.ndarray: ...
    def save(self) -> Any: ...
    def restore(self, token: Any) -> None: ...


class Controller(ABC):
    """Base class; subclasses set ``name`` and implement :meth:`attempt`."""

    name: ClassVar[str]
    needs_rollback: ClassVar[bool] = False

    @abstractmethod
    def initial_step(self, t0: float, t_end: float) -> float: ...

    @abstractmethod
    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt: ...

    def describe(self) -> dict[str, Any]:
        """Settings, for the results store."""
        return {"name": self.name, **{k: v for k, v in vars(self).items()
                                      if not k.startswith("_")}}


class Fixed(Controller):
    """A constant communication step (thesis 4.2.2)."""

    name = "fixed"

    def __init__(self, step: float) -> None:
        if not step > 0:
            raise ValueError(f"`step` must be positive, got {step}")
        self.step = float(step)

    def initial_step(self, t0: float, t_end: float) -> float:
        return self.step

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        return Attempt(ctx.step(t, h), True, self.step)


class Random(Controller):
    """A seeded random step, uniform in ``[hmin, hmax]`` (robustness test of thesis 4.2.2.2)."""

    name = "random"

    def __init__(self, hmin: float = 0.001, hmax: float = 0.01, seed: int = 0) -> None:
        if not 0 < hmin <= hmax:
            raise ValueError(f"need 0 < `hmin` <= `hmax`, got {hmin}, {hmax}")
        self.hmin, self.hmax, self.seed = float(hmin), float(hmax), int(seed)
        self._rng = np.random.default_rng(seed)

    def _draw(self) -> float:
        return float(self._rng.uniform(self.hmin, self.hmax))

    def initial_step(self, t0: float, t_end: float) -> float:
        self._rng = np.random.default_rng(self.seed)
        return self._draw()

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        return Attempt(ctx.step(t, h), True, self._draw())


CONTROLLERS: dict[str, Callable[..., Controller]] = {
    Fixed.name: Fixed,
    Random.name: Random,
}


def make_controller(name: str, step: float | None = None, tol: float | None = None,
                    **options: Any) -> Controller:
    """Build a controller by name from the CLI/config settings.

    ``step`` is the fixed step (``fixed``) or the initial step; ``tol`` the tolerance of the
    adaptive controllers.
    """
    if name not in CONTROLLERS:
        raise ValueError(f"unknown controller '{name}'; choose one of {', '.join(CONTROLLERS)}")
    if name in ("fixed", "random") and tol is not None:
        raise ValueError(f"controller '{name}' does not use a tolerance; drop --tol or choose "
                         "an adaptive controller")
    if name == "fixed":
        if step is None:
            raise ValueError("controller 'fixed' needs a step (--step H or [controller] step)")
        return Fixed(step, **options)
    if name == "random":
        return Random(**options)
    kwargs = dict(options)
    if tol is not None:
        kwargs["tol"] = tol
    if step is not None:
        kwargs["h0"] = step
    return CONTROLLERS[name](**kwargs)
