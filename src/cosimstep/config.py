"""System files: TOML, validated with pydantic, every problem reported at once.

A system file holds shared ``[parameters]`` and ``[start]`` values (so a split model and its
monolithic reference read the same numbers), ``[models.<name>]`` sections, ``[[connections]]``,
optional ``[[parameter_changes]]`` (parameters that change at given times), the run defaults
``[master]`` and ``[controller]``, and an optional ``[reference]`` naming the monolithic model.
See ``docs/system-files.md`` for the full format.

Each section is validated on its own so one bad entry does not hide the problems of the others;
the system-level checks (ports, units, loops) then run on everything that did parse.
"""

from __future__ import annotations

import importlib
import importlib.util
import math
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from cosimstep.adapters.ode import ParameterSchedule, make_solver
from cosimstep.errors import ConfigurationError, Problem
from cosimstep.masters import MasterOptions
from cosimstep.models import REGISTRY
from cosimstep.reference import Reference
from cosimstep.submodel import SubModel
from cosimstep.system import System


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True, allow_inf_nan=False)


class ModelSection(_Section):
    type: str = Field(description="built-in type (see `cosimstep models`), 'python' or 'fmu'")
    parameters: dict[str, Any] = {}  # numbers for built-in types; any TOML value for 'python'
    start: dict[str, float] = {}
    solver: dict[str, Any] | None = None
    class_: str | None = Field(None, alias="class",
                               description="for type = 'python': 'module:Class' or 'file.py:Class'")
    path: str | None = Field(None, description="for type = 'fmu': the .fmu file, relative to "
                             "the system file")
    recipe: str | None = Field(None, description="for type = 'fmu': a built-in FMU built from "
                               "the package's C sources on first use (cosimstep.fmu.build)")


class ConnectionSection(_Section):
    from_: str = Field(alias="from")
    to: str
    gain: float = 1.0
    offset: float = 0.0


class ChangeSection(_Section):
    t: float
    set: dict[str, float]


class MasterSection(_Section):
    name: str = "gauss-seidel"
    extrapolation: int = 2
    order: list[str] | None = None
    call_timeout: float | None = None
    interpolation: str | None = None


class ControllerSection(BaseModel):
    model_config = ConfigDict(extra="allow")
    name: str | None = None
    step: float | None = None
    tol: float | None = None


class ReferenceSection(_Section):
    type: str
    map: dict[str, str]


class HeaderSection(BaseModel):
    model_config = ConfigDict(extra="ignore", allow_inf_nan=False)
    name: str | None = None
    description: str = ""
    until: float = Field(10.0, gt=0)
    parameters: dict[str, float] = {}
    start: dict[str, float] = {}
    solver: dict[str, Any] = {"method": "rk4", "max_dt": 1e-3}


KNOWN_TOP = {"name", "description", "until", "parameters", "start", "solver", "models",
             "connections", "parameter_changes", "master", "controller", "reference"}


@dataclass
class SystemSpec:
    """A loaded system file: the system, its reference and its run defaults."""

    name: str
    source: str
    system: System
    until: float
    master: MasterOptions
    controller: dict[str, Any]
    reference: Reference | None
    raw: dict[str, Any] = field(default_factory=dict)


def _pydantic_problems(where: str, exc: ValidationError) -> list[Problem]:
    out = []
    for e in exc.errors():
        key = ".".join(str(p) for p in e["loc"])
        out.append(Problem(f"{where}.{key}" if key else where, e["msg"],
                           "check the spelling and type of this key"))
    return out


def load_system(path: str | Path, until: float | None = None) -> SystemSpec:
    """Read and check a system file; raise :class:`ConfigurationError` with every problem.

    A path ending in ``.ssp`` is read as an SSP archive (:func:`cosimstep.ssp.load_ssp`).
    """
    path = Path(path)
    src = str(path)
    if path.suffix.lower() == ".ssp":
        from cosimstep.ssp import load_ssp

        return load_ssp(path, until)
    if not path.exists():
        raise ConfigurationError([Problem(src, "file not found", "check the path")], src)
    try:
        raw = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigurationError([Problem(src, f"not valid TOML: {exc}", "fix the syntax")],
                                 src) from exc
    problems: list[Problem] = []
    loc = lambda key: f"{src}: {key}"  # noqa: E731 - tiny local formatter

    for key, kind in (("models", dict), ("connections", list), ("parameter_changes", list)):
        if key in raw and not isinstance(raw[key], kind):
            shape, fix = ("table", f"[{key}.<name>]") if kind is dict else ("list", f"[[{key}]]")
            problems.append(Problem(loc(key), f"must be a {shape}", f"write {fix}"))
            raw = {k: v for k, v in raw.items() if k != key}
    for key in raw:
        if key not in KNOWN_TOP:
            problems.append(Problem(loc(key), "unknown top-level key",
                                    f"known keys: {', '.join(sorted(KNOWN_TOP))}"))
    header = _parse(HeaderSection, raw, loc("[top level]"), problems) or HeaderSection()
    master_sec = _parse(MasterSection, raw.get("master", {}), loc("master"), problems)
    controller_sec = _parse(ControllerSection, raw.get("controller", {}), loc("controller"),
                            problems)
    changes = []
    for i, c in enumerate(raw.get("parameter_changes", [])):
        parsed = _parse(ChangeSection, c, loc(f"parameter_changes[{i}]"), problems)
        if parsed:
            changes.append((parsed.t, parsed.set))

    used_params: set[str] = set()
    system = System()
    base_dir = path.parent
    for name, body in raw.get("models", {}).items():
        where = loc(f"models.{name}")
        sec = _parse(ModelSection, body, where, problems)
        if sec is None:
            continue
        model = _build_model(name, sec, header, changes, base_dir, where, problems, used_params)
        if model is not None:
            try:
                system.add(name, model, where=where)
            except ValueError as exc:
                problems.append(Problem(where, str(exc), "rename the model"))
    for i, body in enumerate(raw.get("connections", [])):
        sec = _parse(ConnectionSection, body, loc(f"connections[{i}]"), problems)
        if sec is not None:
            system.connect(sec.from_, sec.to, sec.gain, sec.offset,
                           where=loc(f"connections[{i}] ({sec.from_} -> {sec.to})"))
    if raw.get("models"):
        problems.extend(system.problems())
    else:
        problems.append(Problem(loc("models"), "no models", "add [models.<name>] sections"))

    reference = None
    if "reference" in raw:
        sec = _parse(ReferenceSection, raw["reference"], loc("reference"), problems)
        if sec is not None:
            reference = _build_reference(sec, header, changes, system, loc("reference"),
                                         problems, used_params)
    for key in header.parameters:
        if key not in used_params:
            problems.append(Problem(loc(f"parameters.{key}"), "no model uses this parameter",
                                    "check the spelling or remove it"))
    for i, (_, values) in enumerate(changes):
        for key in values:
            if key not in used_params:
                problems.append(Problem(loc(f"parameter_changes[{i}].set.{key}"),
                                        "no model uses this parameter", "check the spelling"))
    master = MasterOptions()
    if master_sec is not None:
        master = MasterOptions(master_sec.name, master_sec.extrapolation,
                               tuple(master_sec.order) if master_sec.order else None,
                               master_sec.call_timeout, master_sec.interpolation)
        problems.extend(Problem(loc("master"), p) for p in master.problems())
        for m in master_sec.order or []:
            if m not in system.models:
                problems.append(Problem(loc("master.order"), f"unknown model '{m}'",
                                        f"use names from: {', '.join(system.models)}"))
    if problems:
        raise ConfigurationError(problems, src)
    return SystemSpec(
        name=header.name or path.stem, source=src, system=system,
        until=until if until is not None else header.until, master=master,
        controller=controller_sec.model_dump(exclude_none=True) if controller_sec else {},
        reference=reference, raw=raw)


def _parse(cls: type[BaseModel], body: Any, where: str, problems: list[Problem]) -> Any:
    if not isinstance(body, dict):
        problems.append(Problem(where, "must be a table", "write it as [section] or {...}"))
        return None
    try:
        return cls.model_validate(body)
    except ValidationError as exc:
        problems.extend(_pydantic_problems(where, exc))
        return None


def _build_model(name: str, sec: ModelSection, header: HeaderSection,
                 changes: list[tuple[float, dict[str, float]]], base_dir: Path, where: str,
                 problems: list[Problem], used: set[str]) -> SubModel | None:
    if sec.type == "python":
        return _python_model(sec, base_dir, where, problems)
    if sec.type == "fmu":
        return _fmu_model(name, sec, header, base_dir, where, problems, used)
    for key, given in (("path", sec.path), ("recipe", sec.recipe)):
        if given is not None:
            problems.append(Problem(f"{where}.{key}", f"only used by type 'fmu', not "
                                    f"'{sec.type}'", "remove it or write type = 'fmu'"))
    kind = REGISTRY.get(sec.type)
    if kind is None:
        problems.append(Problem(f"{where}.type", f"unknown model type '{sec.type}'",
                                f"use 'python', 'fmu' or one of: {', '.join(sorted(REGISTRY))}"))
        return None
    bad = [k for k in sec.parameters if k not in kind.parameters]
    for k in bad:
        problems.append(Problem(f"{where}.parameters.{k}", f"'{sec.type}' has no parameter "
                                f"'{k}'", f"its parameters: {', '.join(kind.parameters)}"))
    for k, v in sec.parameters.items():
        if k in kind.parameters and (isinstance(v, bool) or not isinstance(v, int | float)
                                     or not math.isfinite(v)):
            bad.append(k)
            problems.append(Problem(f"{where}.parameters.{k}", f"must be a finite number, got "
                                    f"{v!r}", "write a number"))
    for k in sec.start:
        if k not in kind.start:
            problems.append(Problem(f"{where}.start.{k}", f"'{sec.type}' has no start value "
                                    f"'{k}'", f"it reads: {', '.join(kind.start)}"))
    if bad:
        return None
    shared = {k: v for k, v in header.parameters.items() if k in kind.parameters}
    used.update(shared)
    params = {**kind.parameters, **shared, **sec.parameters}
    own_changes = [(t, {k: v for k, v in vals.items() if k in kind.parameters})
                   for t, vals in changes]
    for _, vals in changes:
        used.update(k for k in vals if k in kind.parameters)
    start = {**header.start, **sec.start}
    try:
        solver = make_solver(sec.solver if sec.solver is not None else header.solver)
    except (TypeError, ValueError) as exc:
        problems.append(Problem(f"{where}.solver", str(exc),
                                "use {method = 'rk4', substeps = n | max_dt = dt} or "
                                "{method = 'RK45', rtol = .., atol = ..}"))
        return None
    return kind.build(ParameterSchedule(params, own_changes), start, solver)


def _fmu_model(name: str, sec: ModelSection, header: HeaderSection, base_dir: Path, where: str,
               problems: list[Problem], used: set[str]) -> SubModel | None:
    # Imported here: FMPy is only loaded when a system actually holds an FMU.
    from cosimstep.fmu.resolve import fmu_submodel, resolve_fmu

    if sec.class_ is not None:
        problems.append(Problem(f"{where}.class", "not used by type 'fmu'", "remove it"))
    fmu = resolve_fmu(sec.path, sec.recipe, base_dir, where, problems)
    if fmu is None:
        return None
    overrides = {f"parameters.{k}": v for k, v in sec.parameters.items()}
    overrides.update({f"start.{k}": v for k, v in sec.start.items()})
    # `solver` is for model-exchange FMUs (integrated by cosimstep); fmu_submodel checks it
    return fmu_submodel(name, fmu, overrides, where, problems, shared=header.parameters,
                        used=used, solver=sec.solver)


def _python_model(sec: ModelSection, base_dir: Path, where: str,
                  problems: list[Problem]) -> SubModel | None:
    target = sec.class_
    if not target or ":" not in target:
        problems.append(Problem(f"{where}.class", "type 'python' needs class = 'module:Class'",
                                "e.g. class = 'mymodels.py:Heater' or 'package.module:Heater'"))
        return None
    module_name, _, cls_name = target.rpartition(":")
    try:
        if module_name.endswith(".py"):
            file = (base_dir / module_name).resolve()
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


def _build_reference(sec: ReferenceSection, header: HeaderSection,
                     changes: list[tuple[float, dict[str, float]]], system: System, where: str,
                     problems: list[Problem], used: set[str]) -> Reference | None:
    kind = REGISTRY.get(sec.type)
    if kind is None:
        problems.append(Problem(f"{where}.type", f"unknown reference model '{sec.type}'",
                                f"use one of: {', '.join(sorted(REGISTRY))}"))
        return None
    shared = {k: v for k, v in header.parameters.items() if k in kind.parameters}
    used.update(shared)
    own_changes = [(t, {k: v for k, v in vals.items() if k in kind.parameters})
                   for t, vals in changes]
    model = kind.build(ParameterSchedule({**kind.parameters, **shared}, own_changes),
                       header.start, None)
    outputs = {f"{n}.{p.name}" for n, m in system.models.items() for p in m.outputs}
    states = {p.name for p in model.outputs}
    for k, v in sec.map.items():
        if k not in outputs:
            problems.append(Problem(f"{where}.map.{k}", "not an output of the system",
                                    "keys are model.output addresses"))
        if v not in states:
            problems.append(Problem(f"{where}.map.{k}", f"'{v}' is not a state of '{sec.type}'",
                                    f"its states: {', '.join(sorted(states))}"))
    return Reference(model, dict(sec.map))
