"""What a system file becomes, whatever its format: a :class:`SystemSpec`.

TOML files (:mod:`cosimstep.config`) and SSP archives (:mod:`cosimstep.ssp`) build their
:class:`~cosimstep.system.System` in their own ways, but share everything else: the header
(name, horizon, shared parameters and start values), the run defaults ``[master]`` and
``[controller]``, the ``[reference]`` naming a monolithic model, and the rule that every problem
is collected before one :class:`~cosimstep.errors.ConfigurationError` lists them all. Both
formats call :func:`parse_header` first (models read the shared values) and :func:`finish`
last; neither imports the other.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, Strict, ValidationError, field_validator

from cosimstep.adapters.ode import ParameterSchedule, make_solver
from cosimstep.errors import ConfigurationError, Problem
from cosimstep.masters import DEFAULT_CALL_TIMEOUT, MasterOptions
from cosimstep.models import REGISTRY, ModelKind
from cosimstep.reference import Reference
from cosimstep.system import System

Changes = list[tuple[float, dict[str, float]]]
"""Parameter changes: ``(time, {parameter: value})``."""

SOLVER_FIX = ("use {method = 'rk4', substeps = n | max_dt = dt} or "
              "{method = 'RK45', rtol = .., atol = ..}")


Number = Annotated[float, Strict()]
"""A number in a system file: an integer or a float, not ``true`` (which a lax float reads as
1: ``until = true`` ran to t = 1 s) and not a string of digits."""


class Section(BaseModel):
    """A strict table: unknown keys, NaN and infinities are problems."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True, allow_inf_nan=False)


class MasterSection(Section):
    name: str = "gauss-seidel"
    extrapolation: int = 2
    order: list[str] | None = None
    call_timeout: Number = DEFAULT_CALL_TIMEOUT
    interpolation: str | None = None
    resync: str = "partial"
    coupling: str = "explicit"
    coupling_tol: Number = 1e-8
    max_iterations: int = 50
    coupling_input: str = "polynomial"

    @field_validator("extrapolation", "max_iterations", mode="before")
    @classmethod
    def _no_switch(cls, value: Any) -> Any:
        """`true` is no number (a lax int would read it as 1); `2.0` still is."""
        if isinstance(value, bool):
            raise ValueError("a whole number, not true/false")
        return value


class ControllerSection(BaseModel):
    model_config = ConfigDict(extra="allow")  # controller options are checked when it is built
    name: str | None = None
    step: Number | None = None
    tol: Number | None = None


class ReferenceSection(Section):
    type: str
    map: dict[str, str]


class HeaderSection(BaseModel):
    model_config = ConfigDict(extra="ignore", allow_inf_nan=False)
    name: str | None = None
    description: str = ""
    until: Number = Field(10.0, gt=0)
    parameters: dict[str, Number] = {}
    start: dict[str, Number] = {}
    solver: dict[str, Any] = {"method": "rk4", "max_dt": 1e-3}


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


def parse(cls: type[BaseModel], body: Any, where: str, problems: list[Problem], *,
          rest: bool = False) -> Any:
    """``cls`` validated from ``body``, or ``None`` with the reasons added to ``problems``.

    ``rest``: where the only problems are extra keys (none resembling a field), the section of
    the others instead of ``None``, so that what is checked on the whole section is checked on
    them too: an unknown key in ``[master]`` hid eight bad values beside it. The refused keys
    are in ``problems`` already, so a run never starts from it."""
    if not isinstance(body, dict):
        problems.append(Problem(where, "must be a table", "write it as [section] or {...}"))
        return None
    try:
        return cls.model_validate(body)
    except ValidationError as exc:
        keys = [f.alias or name for name, f in cls.model_fields.items()]
        unknown = {tuple(e["loc"][:-1]) for e in exc.errors() if e["type"] == "extra_forbidden"}
        for e in exc.errors():
            key = ".".join(str(p) for p in e["loc"])
            what, fix = _plain(e, keys, tuple(e["loc"][:-1]) in unknown)
            problems.append(Problem(f"{where}.{key}" if key else where, what, fix))
        return _rest(cls, body, exc, keys) if rest else None


def _rest(cls: type[BaseModel], body: dict[str, Any], exc: ValidationError,
          keys: list[str]) -> Any:
    """``body`` validated without the keys ``exc`` refused, when they are merely extra (else
    ``None``): a refused value, or a misspelt key standing for one (``nmae``), leaves its field
    at a default the rest would be judged against (multirate-only settings reported against a
    default Gauss-Seidel)."""
    extra = [e for e in exc.errors() if e["type"] == "extra_forbidden"]
    if len(extra) < len(exc.errors()) or any(
            difflib.get_close_matches(str(e["loc"][-1]), keys, n=1) for e in extra):
        return None
    refused = {e["loc"][0] for e in extra if e["loc"]}
    try:
        return cls.model_validate({k: v for k, v in body.items() if k not in refused})
    except ValidationError:
        return None


def _plain(error: Mapping[str, Any], keys: list[str], beside: bool) -> tuple[str, str]:
    """A validation error as a user reads it: a misspelt key is an unknown one with a
    suggestion (and its twin, the required key it should have been, says so too)."""
    name = str(error["loc"][-1]) if error["loc"] else ""
    if error["type"] == "extra_forbidden":
        close = difflib.get_close_matches(name, keys, n=1)
        return "unknown key", (f"did you mean '{close[0]}'?" if close
                               else f"known keys: {', '.join(keys)}")
    if error["type"] == "missing":
        return "required key missing", (f"add {name} = ..." + (" (or correct the unknown key "
                                                               "listed beside)" if beside else ""))
    if error["type"] == "float_type":  # a Number given as true/false or quoted
        given = error["input"]
        shown = str(given).lower() if isinstance(given, bool) else repr(given)
        return f"must be a number, got {shown}", "write the number itself, e.g. 0.01"
    return error["msg"], "check the spelling and type of this key"


def parse_header(settings: Mapping[str, Any], where: str,
                 problems: list[Problem]) -> HeaderSection:
    """The header keys of ``settings`` (defaults where they did not parse).

    The shared ``solver`` is checked here, once: every model that uses it would otherwise
    report the same problem under its own name. A bad one is reported and replaced by the
    default, so the models still build and their own problems are found too."""
    header = parse(HeaderSection, dict(settings), where, problems) or HeaderSection()
    try:
        make_solver(header.solver)
    except (TypeError, ValueError) as exc:
        problems.append(Problem(f"{where}.solver", str(exc), SOLVER_FIX))
        header = header.model_copy(update={"solver": HeaderSection().solver})
    return header


def build_reference(sec: ReferenceSection, header: HeaderSection, changes: Changes,
                    system: System, where: str, problems: list[Problem],
                    used: set[str], refused: frozenset[str] = frozenset()) -> Reference | None:
    """The monolithic reference a ``[reference]`` table names, reading the shared values
    (``refused``: models the file declares that could not be built; their map entries are not
    checked, as their problems are listed already)."""
    kind = REGISTRY.get(sec.type)
    if kind is None:
        problems.append(Problem(f"{where}.type", f"unknown reference model '{sec.type}'",
                                f"use one of: {', '.join(sorted(REGISTRY))}"))
        return None
    shared = {k: v for k, v in header.parameters.items() if k in kind.parameters}
    used.update(shared)
    used.update(f"start.{k}" for k in header.start if k in kind.start)
    own_changes = [(t, {k: v for k, v in vals.items() if k in kind.parameters})
                   for t, vals in changes]
    model = kind.build(ParameterSchedule({**kind.parameters, **shared}, own_changes),
                       header.start, None)
    states = {p.name for p in model.outputs}
    problems += _map_problems(sec, kind, states, system, where, refused)
    measurable = {k: v for k, v in sec.map.items() if v in states or v in kind.derived}
    return Reference(model, measurable, dict(kind.derived))


def _map_problems(sec: ReferenceSection, kind: ModelKind, states: set[str],
                  system: System, where: str, refused: frozenset[str]) -> list[Problem]:
    """A reference map's keys that are no output of the system, and values that are neither a
    state of the monolithic kind nor a quantity it computes from them."""
    outputs = {f"{n}.{p.name}" for n, m in system.models.items() for p in m.outputs}
    problems = []
    for k, v in sec.map.items():
        # a refused model's outputs are unknown: its own problems are listed already
        if k not in outputs and k.partition(".")[0] not in refused:
            problems.append(Problem(f"{where}.map.{k}", "not an output of the system",
                                    "keys are model.output addresses"))
        if v not in states and v not in kind.derived:
            known = f"its states: {', '.join(sorted(states))}"
            if kind.derived:
                known += f"; computed from them: {', '.join(sorted(kind.derived))}"
            problems.append(Problem(f"{where}.map.{k}",
                                    f"'{v}' is not a state of '{sec.type}'", known))
    return problems


def _master(body: Any, system: System, where: str, problems: list[Problem]) -> MasterOptions:
    sec = parse(MasterSection, body, where, problems, rest=True)
    if sec is None:
        return MasterOptions()
    master = MasterOptions(sec.name, sec.extrapolation,
                           tuple(sec.order) if sec.order else None, sec.call_timeout,
                           sec.interpolation, sec.resync, sec.coupling, sec.coupling_tol,
                           sec.max_iterations, sec.coupling_input)
    problems.extend(Problem(where, p, "correct the [master] table (docs/system-files.md)")
                    for p in master.problems())
    for m in sec.order or []:
        if m not in system.models:
            problems.append(Problem(f"{where}.order", f"unknown model '{m}'",
                                    f"use names from: {', '.join(system.models)}"))
    twice = sorted({m for m in sec.order or [] if sec.order.count(m) > 1})
    if twice:
        problems.append(Problem(f"{where}.order", f"names {', '.join(twice)} more than once",
                                "name each model at most once (the others step after them)"))
    return master


def _file_indices(entries: Any, changes: Changes) -> list[int]:
    """Each change's index among the file's ``[[parameter_changes]]`` entries: the changes
    kept only the valid ones, so their own count misnames a later entry once an earlier one
    was refused (found in order: the first entry from there with the same time and names)."""
    entries = entries if isinstance(entries, list) else []
    out, j = [], 0
    for i, (t, values) in enumerate(changes):
        while j < len(entries) and not (isinstance(entries[j], dict)
                                        and entries[j].get("t") == t
                                        and isinstance(entries[j].get("set"), dict)
                                        and set(entries[j]["set"]) == set(values)):
            j += 1
        out.append(j if j < len(entries) else i)
        j += 1
    return out


def _unused(header: HeaderSection, changes: Changes, used: set[str], loc: Callable[[str], str],
            problems: list[Problem], entries: Any = None) -> None:
    for key in header.parameters:
        if key not in used:
            problems.append(Problem(loc(f"parameters.{key}"), "no model uses this parameter",
                                    "check the spelling or remove it"))
    for key in header.start:  # built-in models and the reference read shared start values
        if f"start.{key}" not in used:
            problems.append(Problem(loc(f"start.{key}"), "no model reads this start value",
                                    "check the spelling, or give it to one model: "
                                    "[models.<name>] start = {...}"))
    for i, (_, values) in zip(_file_indices(entries, changes), changes, strict=True):
        for key in values:
            if key not in used:
                fix = ("a change sets a shared parameter ([parameters]); one model's own "
                       "parameters do not change during a run" if "." in key
                       else "check the spelling")
                problems.append(Problem(loc(f"parameter_changes[{i}].set.{key}"),
                                        "no model uses this parameter", fix))


def _check_controller(sec: ControllerSection, where: str, problems: list[Problem]) -> None:
    """The file's ``[controller]`` built once, so that a bad value in it is listed with the
    file's other problems (not found alone, after they were fixed)."""
    from cosimstep.controllers import (
        CONTROLLERS,
        DEFAULT_ADAPTIVE,
        controller_options,
        make_controller,
        plain_error,
    )

    settings = sec.model_dump(exclude_none=True)
    name = settings.pop("name", None)
    if not settings:
        return
    step, tol = settings.pop("step", None), settings.pop("tol", None)
    if name is not None and name not in CONTROLLERS:
        problems.append(Problem(f"{where}.name", f"unknown controller '{name}'",
                                f"choose one of {', '.join(CONTROLLERS)}"))
        return
    # step and tol on their own, and the constructor asked again without each unknown option
    # it names, so that one bad value does not hide the others
    chosen = name or (DEFAULT_ADAPTIVE if tol is not None else "fixed")
    step, tol = _step_and_tol(step, tol, where, problems)
    if step is None and chosen == "fixed":
        step = 1.0  # the command line may still give the step: check the rest with a stand-in
    options = controller_options(chosen)
    while True:
        try:
            make_controller(name, step, tol, **settings)
            return
        except (TypeError, ValueError) as exc:
            unknown = _unknown_option(exc, settings)
            if unknown is None:
                problems.append(Problem(where, plain_error(exc), f"correct the [controller] "
                                        f"table; options of '{chosen}': {', '.join(options)}"))
                return
            close = difflib.get_close_matches(unknown, [*options, "step", "tol"], n=1)
            problems.append(Problem(f"{where}.{unknown}", f"unknown option of '{chosen}'",
                                    f"did you mean '{close[0]}'?" if close
                                    else f"its options: {', '.join(options)}"))
            del settings[unknown]


def _step_and_tol(step: float | None, tol: float | None, where: str,
                  problems: list[Problem]) -> tuple[float | None, float | None]:
    """``[controller]``'s step and tol, each refused on its own where it is no positive number;
    what the rest of the table is checked with (a refused step left out, a refused tol
    standing in as 1e-4)."""
    for key, value in (("step", step), ("tol", tol)):
        if value is not None and not (math.isfinite(value) and value > 0):
            problems.append(Problem(f"{where}.{key}", f"must be a positive number, got {value}",
                                    "e.g. 0.01" if key == "step" else "e.g. 1e-4"))
    step = step if step is not None and math.isfinite(step) and step > 0 else None
    tol = tol if tol is None or (math.isfinite(tol) and tol > 0) else 1e-4
    return step, tol


def _unknown_option(exc: Exception, settings: Mapping[str, Any]) -> str | None:
    """The option a controller's constructor refused as an unexpected keyword, if one of
    ``settings`` (Python names it in ``got an unexpected keyword argument 'x'``)."""
    text = str(exc)
    if not (isinstance(exc, TypeError) and "unexpected keyword argument" in text):
        return None
    key = text.rpartition("argument ")[2].strip("'\"")
    return key if key in settings else None


@dataclass
class Origin:
    """Where a spec came from, for its messages and its summary."""

    source: str  # the file, as the user named it
    loc: Callable[[str], str]  # a settings key -> where to report it
    name: str  # the name when the header gives none
    until: float | None  # the horizon the caller asked for (overrides the file)
    default_until: float | None = None  # the format's own horizon (SSP: DefaultExperiment)


def finish(settings: Mapping[str, Any], header: HeaderSection, system: System, origin: Origin,
           problems: list[Problem], raw: dict[str, Any], *, changes: Changes | None = None,
           used: set[str] | None = None, reference: bool = True) -> SystemSpec:
    """Read the run defaults and the reference of ``settings``, then the spec — or raise
    :class:`ConfigurationError` with every problem collected so far and here.

    ``used`` (the shared parameters some model read): with it, a shared parameter or a change
    nothing reads is a problem (a misspelling would otherwise change nothing, silently).
    ``reference=False`` skips building the reference (its model names would only repeat
    problems already listed for the system).
    """
    changes = changes if changes is not None else []
    loc = origin.loc
    before = len(problems)
    master = _master(settings.get("master", {}), system, loc("master"), problems)
    master_ok, before = len(problems) == before, len(problems)
    controller = parse(ControllerSection, settings.get("controller", {}), loc("controller"),
                       problems)
    if controller is not None:
        _check_controller(controller, loc("controller"), problems)
    controller_ok = controller is not None and len(problems) == before
    ref = None
    if "reference" in settings:
        sec = parse(ReferenceSection, settings["reference"], loc("reference"), problems)
        if sec is not None and reference:
            declared = raw.get("models") if isinstance(raw.get("models"), dict) else {}
            refused = frozenset(m for m in declared if m not in system.models)
            ref = build_reference(sec, header, changes, system, loc("reference"), problems,
                                  used if used is not None else set(), refused)
    if used is not None:
        _unused(header, changes, used, loc, problems, settings.get("parameter_changes"))
    if problems:
        error = ConfigurationError(problems, origin.source)
        # the run defaults as read, so that a command line can check its own choices on top of
        # them and report its problems with these (cosimstep.cli), not after they are fixed
        error.defaults = (master if master_ok else None,
                          controller.model_dump(exclude_none=True) if controller_ok else None)
        raise error
    until = origin.until if origin.until is not None else (
        origin.default_until if origin.default_until is not None else header.until)
    return SystemSpec(
        name=header.name or origin.name, source=origin.source, system=system, until=until,
        master=master, controller=controller.model_dump(exclude_none=True) if controller else {},
        reference=ref, raw=raw)


__all__ = ["ControllerSection", "HeaderSection", "MasterSection", "Number", "Origin",
           "ReferenceSection", "Section", "SystemSpec", "build_reference", "finish", "parse",
           "parse_header"]
