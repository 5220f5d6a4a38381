"""Open any FMU cosimstep runs with the adapter for its FMI version and kind (issue 5).

=====================  ===========================================  ==========================
FMU                    adapter                                      integrates
=====================  ===========================================  ==========================
FMI 2.0 co-simulation  :class:`~cosimstep.adapters.fmu.FmuSubModel`    the FMU's own solver
FMI 3.0 co-simulation  :class:`~cosimstep.adapters.fmu3.Fmu3SubModel`  the FMU's own solver
FMI 2.0 model exchange :class:`~cosimstep.adapters.fmu_me.MeSubModel`  SciPy ``solve_ivp``
FMI 3.0 model exchange :class:`~cosimstep.adapters.fmu_me.MeSubModel`  SciPy ``solve_ivp``
=====================  ===========================================  ==========================

An FMU offering both kinds runs as co-simulation (its own solver) unless ``kind="ME"`` is asked
for. FMI 1.0 and FMI 3.0 scheduled execution are refused by
:func:`~cosimstep.adapters.fmu.check_fmu` with a message saying what is supported.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from cosimstep.adapters.fmu import (
    FMI2_CS,
    FMI2_ME,
    FMI3_CS,
    FMI3_ME,
    SUPPORTED,
    FmuSubModel,
    check_fmu,
    fmu_interface,
)
from cosimstep.adapters.ode import SolveIvp
from cosimstep.submodel import SubModel

__all__ = ["open_fmu"]


def open_fmu(path: str | Path, start: Mapping[str, float] | None = None, *,
             instance_name: str | None = None, kind: str | None = None,
             solver: SolveIvp | Mapping[str, Any] | None = None) -> SubModel:
    """The sub-model running the FMU at ``path``; ``ValueError`` saying why it cannot run.

    Parameters
    ----------
    start:
        Start values and parameters by variable name.
    instance_name:
        Name of the FMU instance; default the model name.
    kind:
        ``"CS"`` or ``"ME"`` to choose the interface of an FMU that offers both; default
        co-simulation when offered.
    solver:
        For model exchange only: ``solve_ivp`` settings, a :class:`~cosimstep.adapters.ode.SolveIvp`
        or a mapping ``{"method": ..., "rtol": ..., "atol": ...}``. Refused for co-simulation,
        whose FMU brings its own solver.
    """
    if kind not in (None, "CS", "ME"):
        raise ValueError(f"`kind` must be 'CS' or 'ME', got {kind!r}")
    wanted = tuple(p for p in SUPPORTED if kind is None or p[1] == kind)
    md = check_fmu(path, wanted)
    chosen = fmu_interface(md, wanted)
    if chosen not in (FMI2_ME, FMI3_ME) and solver is not None:
        raise ValueError(f"`solver` is only for model-exchange FMUs; {Path(path).name} runs as "
                         f"FMI {chosen[0]} co-simulation with its own solver")
    if chosen == FMI2_CS:
        return FmuSubModel(path, start, instance_name=instance_name)
    if chosen == FMI3_CS:
        from cosimstep.adapters.fmu3 import Fmu3SubModel

        return Fmu3SubModel(path, start, instance_name=instance_name)
    from cosimstep.adapters.fmu_me import MeSubModel, make_me_solver

    if solver is not None and not isinstance(solver, SolveIvp):
        solver = make_me_solver(solver)
    return MeSubModel(path, start, instance_name=instance_name, solver=solver)
