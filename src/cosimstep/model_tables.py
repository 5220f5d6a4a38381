"""One ``[models.<name>]`` table into a sub-model, shared by TOML system files and SSP.

A TOML file's model tables (:mod:`cosimstep.config`) and an SSP archive's components that name a
built-in type (:mod:`cosimstep.ssp`) are built by the same :func:`build_model`, with the file's
shared ``[parameters]``, ``[start]``, ``solver`` and ``[[parameter_changes]]``, so the two
formats cannot drift apart; both import this module, neither the other.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

from pydantic import Field

from cosimstep.adapters.ode import ParameterSchedule, make_solver
from cosimstep.errors import Problem
from cosimstep.events import KINDS as EVENT_KINDS
from cosimstep.models import REGISTRY
from cosimstep.spec import SOLVER_FIX, Changes, HeaderSection, Number, Section, parse
from cosimstep.submodel import SubModel


class ModelSection(Section):
    type: str = Field(description="built-in type (see `cosimstep models`), 'python' or 'fmu'")
    # numbers for built-in types; any TOML value for 'python'
    parameters: dict[str, Any] = Field(default_factory=dict)
    # numbers; arrays (nested lists) for an FMU's array variables
    start: dict[str, float | list[Any]] = Field(default_factory=dict)
    solver: dict[str, Any] | None = None
    class_: str | None = Field(None, alias="class",
                               description="for type = 'python': 'module:Class' or 'file.py:Class'")
    path: str | None = Field(None, description="for type = 'fmu': the .fmu file, relative to "
                             "the system file")
    recipe: str | None = Field(None, description="for type = 'fmu': a built-in FMU built from "
                               "the package's C sources on first use (cosimstep.fmu.build)")
    export: str | None = Field(None, description="for type = 'fmu': a built-in type exported "
                               "as an FMI 2.0 FMU with pythonfmu on first use (cosimstep export)")
    interface: Literal["co-simulation", "model-exchange"] | None = Field(
        None, description="for type = 'fmu' offering both: which one runs (default: "
        "co-simulation)")


class ChangeSection(Section):
    t: Number
    set: dict[str, Number]


def parse_changes(raw: dict[str, Any], loc: Callable[[str], str],
                  problems: list[Problem]) -> Changes:
    """The ``[[parameter_changes]]`` of a system file (or an SSP's cosimstep annotation)."""
    changes: Changes = []
    first: dict[tuple[float, str], tuple[int, float]] = {}  # (t, name): where set, to what
    for i, c in enumerate(raw.get("parameter_changes", [])):
        parsed = parse(ChangeSection, c, loc(f"parameter_changes[{i}]"), problems)
        if not parsed:
            continue
        if parsed.t < 0.0:
            problems.append(Problem(loc(f"parameter_changes[{i}].t"), f"{parsed.t:g} is before "
                                    "the run starts (t = 0)", "give the value from the start "
                                    "in [parameters], or a time >= 0"))
            continue
        for key, value in parsed.set.items():
            j, earlier = first.setdefault((parsed.t, key), (i, value))
            if earlier != value:
                problems.append(Problem(loc(f"parameter_changes[{i}].set.{key}"),
                                        f"parameter_changes[{j}] sets it to {earlier:g} at the "
                                        f"same time t = {parsed.t:g}", "keep one of them"))
        changes.append((parsed.t, parsed.set))
    return changes


def build_model(name: str, sec: ModelSection, header: HeaderSection,
                changes: Changes, base_dir: Path, where: str,
                problems: list[Problem], used: set[str]) -> SubModel | None:
    """The sub-model of one ``[models.<name>]`` table (also an SSP component naming a built-in
    type, :mod:`cosimstep.ssp`); ``None`` after recording its problems."""
    if sec.type == "python":
        return _python_model(sec, base_dir, where, problems)
    if sec.type == "fmu":
        return _fmu_model(name, sec, header, base_dir, where, problems, used)
    if sec.type in EVENT_KINDS:
        return _event_model(sec, where, problems)
    for key, given in (("path", sec.path), ("recipe", sec.recipe), ("export", sec.export)):
        if given is not None:
            problems.append(Problem(f"{where}.{key}", f"only used by type 'fmu', not "
                                    f"'{sec.type}'", "remove it or write type = 'fmu'"))
    kind = REGISTRY.get(sec.type)
    if kind is None:
        known = sorted([*REGISTRY, *EVENT_KINDS])
        problems.append(Problem(f"{where}.type", f"unknown model type '{sec.type}'",
                                f"use 'python', 'fmu' or one of: {', '.join(known)}"))
        return None
    # the shared values this type reads count as read even if the model is refused below:
    # its own problem is the one to report, not "no model uses ..." for each of them
    shared = {k: v for k, v in header.parameters.items() if k in kind.parameters}
    used.update(shared)
    for _, vals in changes:
        used.update(k for k in vals if k in kind.parameters)
    used.update(f"start.{k}" for k in header.start if k in kind.start)
    if not _builtin_values_ok(sec, kind, where, problems):
        return None
    params = {**kind.parameters, **shared, **sec.parameters}
    own_changes = [(t, {k: v for k, v in vals.items() if k in kind.parameters})
                   for t, vals in changes]
    start = {**header.start, **sec.start}
    try:
        solver = make_solver(sec.solver if sec.solver is not None else header.solver)
    except (TypeError, ValueError) as exc:
        problems.append(Problem(f"{where}.solver", str(exc), SOLVER_FIX))
        return None
    return kind.build(ParameterSchedule(params, own_changes), start, solver)


def _builtin_values_ok(sec: ModelSection, kind: Any, where: str,
                       problems: list[Problem]) -> bool:
    """A built-in type's parameters must be its own and finite numbers; start values must name
    what it reads (an unknown start value is reported but does not stop the build)."""
    ok = True
    for k, v in sec.parameters.items():
        if k not in kind.parameters:
            problems.append(Problem(f"{where}.parameters.{k}", f"'{sec.type}' has no parameter "
                                    f"'{k}'", f"its parameters: {', '.join(kind.parameters)}"))
            ok = False
        elif isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            problems.append(Problem(f"{where}.parameters.{k}", f"must be a finite number, got "
                                    f"{v!r}", "write a number"))
            ok = False
    for k, v in sec.start.items():
        if k not in kind.start:
            problems.append(Problem(f"{where}.start.{k}", f"'{sec.type}' has no start value "
                                    f"'{k}'", f"it reads: {', '.join(kind.start)}"))
        elif isinstance(v, list):
            problems.append(Problem(f"{where}.start.{k}", "must be a number, got a list",
                                    "write a number (arrays are for FMU array variables)"))
            ok = False
    return ok


def _fmu_model(name: str, sec: ModelSection, header: HeaderSection, base_dir: Path, where: str,
               problems: list[Problem], used: set[str]) -> SubModel | None:
    # Imported here: FMPy is only loaded when a system actually holds an FMU.
    from cosimstep.fmu.resolve import fmu_submodel, resolve_fmu

    if sec.class_ is not None:
        problems.append(Problem(f"{where}.class", "not used by type 'fmu'", "remove it"))
    # `solver` is the exported sub-model's internal solver (default: the file's), or the
    # integrator of a model-exchange FMU (fmu_submodel checks it)
    exported = None if sec.export is None else (sec.export, sec.solver or header.solver)
    fmu = resolve_fmu(sec.path, sec.recipe, base_dir, where, problems, export=exported)
    if fmu is None:
        return None
    overrides = {f"parameters.{k}": v for k, v in sec.parameters.items()}
    overrides.update({f"start.{k}": v for k, v in sec.start.items()})
    return fmu_submodel(name, fmu, overrides, where, problems, shared=header.parameters,
                        used=used, solver=None if exported else sec.solver,
                        interface=sec.interface)


def _event_model(sec: ModelSection, where: str, problems: list[Problem]) -> SubModel | None:
    """A discrete-event kind (:mod:`cosimstep.events`) from its ``parameters`` table."""
    cls, _ = EVENT_KINDS[sec.type]
    for key, given in (("path", sec.path), ("recipe", sec.recipe), ("export", sec.export),
                       ("class", sec.class_), ("solver", sec.solver)):
        if given is not None:
            problems.append(Problem(f"{where}.{key}", f"not used by type '{sec.type}'",
                                    "remove it"))
    if sec.start:
        problems.append(Problem(f"{where}.start", f"type '{sec.type}' has no start values",
                                "give its outputs' first values as parameters"))
    past = [t for t in sec.parameters.get("times", []) if isinstance(t, int | float) and t < 0]
    if sec.type == "timetable" and past:
        problems.append(Problem(f"{where}.parameters.times", f"times {past} are before the "
                                "start (runs start at t = 0)", "give times >= 0"))
        return None
    accepted = [p for p in inspect.signature(cls).parameters if p != "self"]
    unknown = [k for k in sec.parameters if k not in accepted]
    for k in unknown:
        problems.append(Problem(f"{where}.parameters.{k}", f"type '{sec.type}' has no "
                                f"parameter '{k}'", f"its parameters: {', '.join(accepted)}"))
    if unknown:
        return None
    try:
        return cls(**sec.parameters)
    except (TypeError, ValueError) as exc:
        problems.append(Problem(f"{where}.parameters", str(exc),
                                f"see docs/system-files.md, type '{sec.type}'"))
        return None


def _python_model(sec: ModelSection, base_dir: Path, where: str,
                  problems: list[Problem]) -> SubModel | None:
    # keys a Python class never reads: silently ignored, a start value looked as if it set
    # the state (the run started from the class's own)
    for key, given, fix in (
            ("path", sec.path, "remove it, or write type = 'fmu'"),
            ("recipe", sec.recipe, "remove it, or write type = 'fmu'"),
            ("export", sec.export, "remove it, or write type = 'fmu'"),
            ("interface", sec.interface, "remove it, or write type = 'fmu'"),
            ("solver", sec.solver, "give the class its solver settings in [parameters]"),
            ("start", sec.start or None, "give the class its start values in [parameters]")):
        if given is not None:
            problems.append(Problem(f"{where}.{key}", "not used by type 'python': the class "
                                    "is built from [parameters] alone", fix))
    target = sec.class_
    if not target or ":" not in target:
        problems.append(Problem(f"{where}.class", "type 'python' needs class = 'module:Class'",
                                "e.g. class = 'mymodels.py:Heater' or 'package.module:Heater'"))
        return None
    module_name, _, cls_name = target.rpartition(":")
    try:
        if module_name.endswith(".py"):
            file = (base_dir / module_name).resolve()
            # the file may import what lies beside it: its folder goes on the path, last, so
            # an installed package of the same name wins (the file itself is executed afresh
            # on every load; what it imports is cached as any import is)
            if str(file.parent) not in sys.path:
                sys.path.append(str(file.parent))
            spec = importlib.util.spec_from_file_location(file.stem, file)
            if spec is None or spec.loader is None:
                raise ImportError(f"cannot load {file}")
            module = importlib.util.module_from_spec(spec)
            sys.modules.setdefault(file.stem, module)
            spec.loader.exec_module(module)
        else:
            module = importlib.import_module(module_name)
        cls = getattr(module, cls_name)
        model = cls(**sec.parameters)
    except Exception as exc:
        problems.append(Problem(f"{where}.class", f"cannot create '{target}': "
                                f"{type(exc).__name__}: {exc}", "check the module path and "
                                "the constructor arguments given as [parameters]"))
        return None
    if not isinstance(model, SubModel):
        problems.append(Problem(f"{where}.class", f"'{target}' is not a cosimstep.SubModel",
                                "subclass cosimstep.SubModel"))
        return None
    return model


__all__ = ["ChangeSection", "ModelSection", "build_model", "parse_changes"]
