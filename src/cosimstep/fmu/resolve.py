"""FMUs named by system files: find or build the archive, check overrides, create the sub-model.

Both system formats go through here — a TOML ``[models.<name>]`` section with ``type = "fmu"``
and an SSP component — so an FMU is refused, and its overrides are checked, the same way in
both. Every problem is appended to the caller's list as a :class:`~cosimstep.errors.Problem`
(where, what, fix) instead of being raised, so one bad FMU does not hide the others.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from cosimstep.errors import Problem
from cosimstep.submodel import ELEMENT, SubModel

if TYPE_CHECKING:
    from fmpy.model_description import ModelDescription, ModelVariable

    from cosimstep.adapters.ode import SolveIvp

RECIPE_SCHEME = "cosimstep:recipe:"  # an SSP component source naming a built-in FMU
_SETTABLE_CAUSALITY = ("parameter", "input", "output")


def build_recipe(recipe: str, where: str, problems: list[Problem]) -> Path | None:
    """Build a built-in FMU (or reuse the cached build); ``None`` after recording a problem."""
    from cosimstep.fmu.build import RECIPES, FmuBuildError, build_fmu

    if recipe not in RECIPES:
        problems.append(Problem(where, f"unknown built-in FMU recipe '{recipe}'",
                                f"use one of: {', '.join(sorted(RECIPES))}"))
        return None
    try:
        return build_fmu(recipe)
    except (FmuBuildError, OSError) as exc:
        problems.append(Problem(where, f"cannot build the FMU '{recipe}': {exc}",
                                "install gcc, or give the path of a built .fmu instead"))
        return None


def build_export(kind: str, solver: Mapping[str, Any] | None, where: str,
                 problems: list[Problem]) -> Path | None:
    """A built-in Python sub-model exported as an FMU (:func:`~cosimstep.fmu.export.export_fmu`
    with the kind's defaults and this internal ``solver``), kept in the build cache; ``None``
    after recording a problem.

    The FMU runs the installed cosimstep inside, so only its interface and configuration are
    fixed at export: the cache key is the kind, the solver and the source of the exporter and
    of the kind's module.
    """
    import hashlib
    import inspect
    import json

    from cosimstep.fmu.build import cache_dir
    from cosimstep.models import REGISTRY

    model_kind = REGISTRY.get(kind)
    if model_kind is None:
        problems.append(Problem(where, f"unknown built-in type '{kind}'",
                                "use one of `cosimstep models`, e.g. 'ship.zone1'"))
        return None
    try:
        from cosimstep.fmu import export
    except ImportError as exc:
        problems.append(Problem(where, f"cannot export '{kind}': {exc}",
                                'install pythonfmu: pip install "cosimstep[export]"'))
        return None
    digest = hashlib.sha256(json.dumps([kind, solver], sort_keys=True).encode())
    builder = getattr(model_kind.build, "func", model_kind.build)  # through functools.partial
    for source in (export, builder):
        file = inspect.getsourcefile(source)
        digest.update(Path(file).read_bytes() if file else b"")
    target = (cache_dir() / "fmu" / f"export-{kind.replace('.', '_')}-"
              f"{digest.hexdigest()[:16]}.fmu")
    if target.is_file():
        return target
    try:
        return export.export_fmu(kind, target, solver=solver)
    except (ValueError, OSError) as exc:
        problems.append(Problem(where, f"cannot export '{kind}' as an FMU: {exc}",
                                "check the section's solver"))
        return None


def resolve_fmu(path: str | None, recipe: str | None, base_dir: Path, where: str,
                problems: list[Problem], *,
                export: tuple[str, Mapping[str, Any] | None] | None = None) -> Path | None:
    """The ``.fmu`` of a TOML model section: ``path`` (relative to the file), ``recipe`` (C
    sources) or ``export`` (a built-in Python kind and its internal solver)."""
    if sum(given is not None for given in (path, recipe, export)) != 1:
        problems.append(Problem(where, "type 'fmu' needs exactly one of `path`, `recipe` and "
                                "`export`", "write path = 'model.fmu' (relative to this file), "
                                "recipe = 'pendulum_bar1' or export = 'ship.zone1'"))
        return None
    if recipe is not None:
        return build_recipe(recipe, f"{where}.recipe", problems)
    if export is not None:
        return build_export(*export, f"{where}.export", problems)
    assert path is not None
    file = (base_dir / path).resolve()
    if not file.is_file():
        problems.append(Problem(f"{where}.path", f"no such file: {file}",
                                "give the .fmu path relative to the system file"))
        return None
    return file


def fmu_submodel(name: str, fmu: Path, overrides: Mapping[str, Any], where: str,
                 problems: list[Problem], *, shared: Mapping[str, float] | None = None,
                 used: set[str] | None = None,
                 solver: Mapping[str, Any] | None = None,
                 interface: str | None = None) -> SubModel | None:
    """Create the sub-model of an FMU (:func:`~cosimstep.adapters.fmu_open.open_fmu`: FMI 2.0 or
    3.0 co-simulation or model exchange, the latter integrated by cosimstep) with checked overrides.

    Parameters
    ----------
    overrides:
        ``{"<key>.<variable>": value}`` where ``<key>`` is ``parameters`` or ``start`` (how the
        value was written, for messages); ``parameters`` must name FMU parameters, ``start`` may
        name any variable whose start value can be set.
    shared:
        A system's shared parameters: each one whose name is an FMU parameter is applied (and
        added to ``used``) unless an override names it too.
    solver:
        ``solve_ivp`` settings of a model-exchange FMU (``method``, ``rtol``, ``atol``); a
        problem for a co-simulation FMU, which brings its own solver.
    interface:
        ``"co-simulation"`` or ``"model-exchange"`` for an FMU that offers both (default:
        co-simulation); a problem if the FMU does not offer it.
    """
    from cosimstep.adapters.fmu_open import open_fmu

    kind = {"co-simulation": "CS", "model-exchange": "ME", None: None}[interface]
    md = _checked_description(fmu, solver, where, problems, kind)
    if md is None:
        return None
    by_name = {v.name: v for v in md.modelVariables}
    values = _shared_values(by_name, shared, used)
    if not _apply_overrides(md.modelName, by_name, overrides, values, where, problems):
        return None
    if solver is not None:
        solver = _me_solver(solver, where, problems)
        if solver is None:
            return None
    try:
        return open_fmu(fmu, values, instance_name=name, solver=solver, kind=kind)
    except ValueError as exc:
        problems.append(Problem(where, str(exc), "set only parameters and start values the "
                                "FMU allows to be set"))
        return None


def _me_solver(solver: Mapping[str, Any], where: str,
               problems: list[Problem]) -> SolveIvp | None:
    """The integrator a model-exchange FMU's ``solver`` settings describe; ``None`` after
    recording a problem."""
    from cosimstep.adapters.fmu_me import make_me_solver

    try:
        return make_me_solver(solver)
    except ValueError as exc:
        problems.append(Problem(f"{where}.solver", str(exc),
                                "write {method = 'RK45', rtol = 1e-8, atol = 1e-10}"))
        return None


def _checked_description(fmu: Path, solver: Mapping[str, Any] | None, where: str,
                         problems: list[Problem],
                         kind: str | None = None) -> ModelDescription | None:
    """The FMU's model description if cosimstep can run it (through interface ``kind``,
    ``"CS"`` or ``"ME"``, if given; with ``solver`` only for model exchange); ``None`` after
    recording a problem."""
    from cosimstep.adapters.fmu import SUPPORTED, check_fmu, fmu_interface

    wanted = tuple(p for p in SUPPORTED if kind is None or p[1] == kind)
    try:
        md = check_fmu(fmu, wanted)
    except ValueError as exc:
        fix = ("use an FMI 2.0 or 3.0 co-simulation or model-exchange FMU built for "
               "this platform (`cosimstep info FILE.fmu` shows what it is)")
        if kind is not None:
            fix = "choose an interface the FMU offers (`cosimstep info FILE.fmu`), or drop " \
                "`interface`"
        problems.append(Problem(f"{where}.interface" if kind else where, str(exc), fix))
        return None
    chosen = fmu_interface(md, wanted)
    if solver is not None and (chosen is None or chosen[1] != "ME"):
        problems.append(Problem(f"{where}.solver", "only a model-exchange FMU takes a solver",
                                "remove it (a co-simulation FMU brings its own solver)"))
        return None
    return md


def _shared_values(by_name: Mapping[str, ModelVariable], shared: Mapping[str, float] | None,
                   used: set[str] | None) -> dict[str, Any]:
    """The system's shared parameters this FMU has, marked as ``used`` so that the system can
    report the ones no model took."""
    values: dict[str, Any] = {}
    for k, v in (shared or {}).items():
        if k in by_name and by_name[k].causality == "parameter":
            values[k] = v
            if used is not None:
                used.add(k)
    return values


def _apply_overrides(model_name: str, by_name: Mapping[str, ModelVariable],
                     overrides: Mapping[str, Any], values: dict[str, Any], where: str,
                     problems: list[Problem]) -> bool:
    """Add the valid overrides to ``values``; every bad one is recorded, so ``False`` after
    reporting them all rather than only the first."""
    ok = True
    for key, value in overrides.items():
        problem = _override_problem(model_name, by_name, key, value, where)
        if problem is None:
            values[key.partition(".")[2]] = value
        else:
            problems.append(problem)
            ok = False
    return ok


def _override_problem(model_name: str, by_name: Mapping[str, ModelVariable], key: str,
                      value: Any, where: str) -> Problem | None:
    """What is wrong with one override ``"<parameters|start>.<variable>" = value``, if anything.
    ``variable`` may name one element of an array, ``A[2,1]`` (its index is checked when the
    FMU is opened)."""
    kind, _, var = key.partition(".")
    v = by_name.get(var)
    element = ELEMENT.match(var)
    if v is None and element and element.group(1) in by_name:
        v = by_name[element.group(1)]
        if not _finite_number(value):
            return Problem(f"{where}.{key}", f"must be a finite number, got {value!r}",
                           "write a number")
    if v is None:
        known, label = _settable_names(by_name, kind)
        return Problem(f"{where}.{key}", f"FMU '{model_name}' has no variable '{var}'",
                       f"its {label}: {', '.join(known) or 'none'}")
    if kind == "parameters" and v.causality != "parameter":
        return Problem(f"{where}.{key}", f"'{var}' has causality {v.causality}, not parameter",
                       "set its start value under `start` instead")
    problem = _value_problem(v, var, value)
    return None if problem is None else Problem(f"{where}.{key}", *problem)


def _finite_number(value: Any) -> bool:
    return (not isinstance(value, bool) and isinstance(value, int | float)
            and math.isfinite(value))


def _value_problem(v: ModelVariable, var: str, value: Any) -> tuple[str, str] | None:
    """Why ``value`` does not suit variable ``v`` (message, fix), if it does not."""
    if v.type in ("String", "Binary"):
        if isinstance(value, str):
            return None
        return (f"'{var}' is a {v.type}, got {value!r}",
                'write it in quotes, e.g. "text"' if v.type == "String" else
                'write its bytes in hexadecimal, e.g. "c0ffee"')
    if v.type == "Boolean" and isinstance(value, bool):
        return None
    if v.dimensions and isinstance(value, list):
        flat = np.asarray(value, dtype=object).ravel() if value else np.zeros(0)
        if flat.size and all(_finite_number(x) for x in flat):
            return None
        return (f"'{var}' is an array: give a list of numbers (nested for a matrix), got "
                f"{value!r}", "e.g. [1.0, 0.0, 0.0]")
    if isinstance(value, str) or (isinstance(value, float) and not math.isfinite(value)):
        return f"must be a finite number, got {value!r}", "write a number"
    return None


def _settable_names(by_name: Mapping[str, ModelVariable],
                    kind: str) -> tuple[list[str], str]:
    """The names an override of ``kind`` may use, and what to call them, for the message about
    an unknown one."""
    if kind == "parameters":
        return sorted(n for n, v in by_name.items() if v.causality == "parameter"), "parameters"
    return (sorted(n for n, v in by_name.items() if v.causality in _SETTABLE_CAUSALITY
                   and v.variability != "constant"), "settable variables")
