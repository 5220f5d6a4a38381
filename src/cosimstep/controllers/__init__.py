"""Step-size controllers: they decide the communication step ΔT (thesis 4.2).

Selectable by name (:data:`CONTROLLERS`, :func:`make_controller`) from the API, the system file's
``[controller]`` table and ``cosimstep run --controller``. ``--tol`` alone selects
:data:`DEFAULT_ADAPTIVE`, the controller measured best in docs/benchmarks.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from cosimstep.controllers.base import Attempt, Controller, StepContext, StepPolicy
from cosimstep.controllers.basic import Fixed, Random
from cosimstep.controllers.coupling import Corrector, Defect, Doubling, Embedded, PredictorCorrector
from cosimstep.controllers.curvature import Curvature
from cosimstep.controllers.helpers import AdaptiveTolerance, Switching, fft_hmax, fixed_step_from
from cosimstep.controllers.rkf import RKF23, RKF45
from cosimstep.errors import is_number

CONTROLLERS: dict[str, Callable[..., Controller]] = {
    c.name: c for c in (Fixed, Random, Curvature, RKF23, RKF45, Defect, PredictorCorrector,
                        Corrector, Doubling, Embedded, Switching, AdaptiveTolerance)
}

DEFAULT_ADAPTIVE = "pc"
"""What ``--tol`` without ``--controller`` runs (see docs/benchmarks.md for why)."""

ADAPTIVE = frozenset(CONTROLLERS) - {"fixed", "random", "curvature"}


def make_controller(name: str | None, step: float | None = None, tol: float | None = None,
                    **options: Any) -> Controller:
    """Build a controller by name from the CLI/config settings.

    ``step`` is the fixed step (``fixed``) or the initial step; ``tol`` the tolerance of the
    adaptive controllers. ``name=None`` picks ``fixed`` without ``tol`` and
    :data:`DEFAULT_ADAPTIVE` with it.
    """
    if name is None:
        name = DEFAULT_ADAPTIVE if tol is not None else "fixed"
    if name not in CONTROLLERS:
        raise ValueError(f"unknown controller '{name}'; choose one of {', '.join(CONTROLLERS)}")
    if name not in ADAPTIVE and tol is not None:
        raise ValueError(f"controller '{name}' does not use a tolerance; drop --tol or choose "
                         f"an adaptive controller ({', '.join(sorted(ADAPTIVE))})")
    if name == "fixed":
        if step is None:
            raise ValueError("controller 'fixed' needs a step (--step H or [controller] step)")
        return Fixed(step, **options)
    if step is not None and not (is_number(step) and 0 < step < math.inf):
        # the initial step: a negative one ran (clamped to hmin) where the file refused it
        raise ValueError(f"`step` (the initial step) must be a positive finite number, got "
                         f"{step!r}")
    if name == "random":
        return Random(**options)
    kwargs = dict(options)
    if tol is not None:
        kwargs["tol"] = tol
    if step is not None:
        kwargs["h0"] = step
    return CONTROLLERS[name](**kwargs)


def plain_error(exc: Exception) -> str:
    """Why :func:`make_controller` refused, as a user reads it: Python's ``__init__() got an
    unexpected keyword argument 'x'`` becomes ``unknown option 'x'``."""
    text = str(exc)
    if isinstance(exc, TypeError) and "unexpected keyword argument" in text:
        return f"unknown option {text.rpartition('argument ')[2]}"
    return text


def merged_settings(file: dict[str, Any], controller: str | None, step: float | None,
                    tol: float | None, seed: int | None = None,
                    options: dict[str, Any] | None = None) -> dict[str, Any]:
    """A system file's ``[controller]`` with a run's choices on top: another controller drops
    the file's options (they belong to the file's); a tolerance alone picks the default
    adaptive controller; then ``step``, ``tol``, ``seed`` and ``options`` override."""
    settings: dict[str, Any] = dict(file)
    if controller is not None and controller != settings.get("name"):
        settings = {"name": controller}
    elif controller is None and tol is not None and settings.get("name") not in ADAPTIVE:
        settings = {"name": DEFAULT_ADAPTIVE}
    for key, value in (("step", step), ("tol", tol), ("seed", seed)):
        if value is not None:
            settings[key] = value
    settings.update(options or {})
    return settings


def controller_options(name: str | None) -> list[str]:
    """The options a controller takes by name (its own and, for the error-controlled ones, the
    :class:`StepPolicy` fields), for messages that list them."""
    import dataclasses
    import inspect

    cls = CONTROLLERS[name or "fixed"]
    params = inspect.signature(cls.__init__).parameters
    own = [p for p in params if p not in ("self", "policy", "options", "kwargs")]
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        own += [f.name for f in dataclasses.fields(StepPolicy) if f.name not in own]
    return own


__all__ = ["ADAPTIVE", "CONTROLLERS", "DEFAULT_ADAPTIVE", "RKF23", "RKF45", "AdaptiveTolerance",
           "Attempt", "Controller", "Corrector", "Curvature", "Defect", "Doubling", "Embedded",
           "Fixed", "PredictorCorrector", "Random", "StepContext", "StepPolicy", "Switching",
           "controller_options", "fft_hmax", "fixed_step_from", "make_controller",
           "merged_settings", "plain_error"]
