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

import tomllib
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from pydantic import Field

from cosimstep.errors import ConfigurationError, Problem
from cosimstep.model_tables import ChangeSection, ModelSection, build_model, parse_changes
from cosimstep.spec import (
    Changes,
    HeaderSection,
    Number,
    Origin,
    Section,
    SystemSpec,
    finish,
    parse,
    parse_header,
)
from cosimstep.system import System


class ConnectionSection(Section):
    from_: str = Field(alias="from")
    to: str
    gain: Number = 1.0
    offset: Number = 0.0
    round: bool = False  # into an integer or boolean input: round to the nearest integer


KNOWN_TOP = {"name", "description", "until", "parameters", "start", "solver", "models",
             "connections", "parameter_changes", "master", "controller", "reference"}


def load_system(path: str | Path, until: float | None = None,
                overrides: dict[str, dict[str, Any]] | None = None,
                inputs: str | Path | None = None) -> SystemSpec:
    """Read and check a system file; raise :class:`ConfigurationError` with every problem.

    ``overrides`` changes values without editing the file: ``{"parameters": {NAME: value},
    "start": {NAME: value}}``, where NAME is a shared value (``l2``) or one sub-model's
    (``bar2.l2``); a name nothing reads is reported like a misspelt one in the file. A path
    ending in ``.ssp`` is read as an SSP archive (:func:`cosimstep.ssp.load_ssp`), one ending in
    ``.fmu`` as a system of that FMU alone (:func:`_single_fmu`), its inputs read from the
    CSV file ``inputs`` if given (:class:`~cosimstep.adapters.table.InputTable`).
    """
    path = Path(path)
    src = str(path)
    if inputs is not None and path.suffix.lower() != ".fmu":
        raise ConfigurationError([Problem("--inputs", "a CSV of inputs is for one FMU run alone",
                                          "in a system file, add a timetable model")], src)
    if path.suffix.lower() == ".ssp":
        from cosimstep.ssp import load_ssp

        dotted = [f"{'--param' if t == 'parameters' else '--start'} {n}"
                  for t, values in (overrides or {}).items() for n in values if "." in n]
        if dotted:
            raise ConfigurationError([Problem(d, "one sub-model's values are for TOML systems",
                                              "set them in the SSP's parameter bindings, or "
                                              "give a shared name (without the model)")
                                      for d in dotted], src)
        return load_ssp(path, until, overrides)
    raw = _single_fmu(path) if path.suffix.lower() == ".fmu" else _read_toml(path)
    problems: list[Problem] = []
    given = {f"{table}.{name}": f"{'--param' if table == 'parameters' else '--start'} {name}"
             for table, values in (overrides or {}).items() for name in values}

    def loc(key: str) -> str:
        """Where to report ``key``: the command line for a value given there, else the file
        (a shared value given with --param/--start is checked like one in the file)."""
        return given.get(key, f"{src}: {key}")

    raw = _known_top(raw, loc, problems)
    _override(raw, overrides or {}, problems)
    header = parse_header(raw, loc("[top level]"), problems)
    changes = parse_changes(raw, loc, problems)
    used: set[str] = set()
    system = _build_system(raw, header, changes, path.parent, loc, problems, used)
    if inputs is not None and not problems:
        _feed_from_table(raw, system, inputs, problems)
    return finish(raw, header, system, Origin(src, loc, path.stem, until), problems, raw,
                  changes=changes, used=used)


def _single_fmu(path: Path) -> dict[str, Any]:
    """A system file's content for one FMU run alone, as ``fmpy simulate`` runs it: until its
    default experiment's stop time (1 s without one), at a fixed step of its default step size
    (or 1/500 of the run, FMPy's output interval); its inputs keep their start values."""
    from fmpy import read_model_description

    if not path.is_file():
        raise ConfigurationError([Problem(str(path), "no such file",
                                          "give the path of an existing .fmu")], str(path))
    try:
        experiment = read_model_description(str(path)).defaultExperiment
    except Exception as exc:  # not a zip, no modelDescription.xml, bad XML
        raise ConfigurationError([Problem(str(path), f"cannot read the FMU: {exc}",
                                          "check the file with `cosimstep info`")],
                                 str(path)) from exc
    start = float(getattr(experiment, "startTime", None) or 0.0)
    stop = float(getattr(experiment, "stopTime", None) or start + 1.0)
    step = getattr(experiment, "stepSize", None)
    step = float(step) if step else (stop - start) / 500
    name = "".join(c if c.isalnum() or c == "_" else "_" for c in path.stem) or "fmu"
    return {"name": name, "until": stop,
            "models": {name: {"type": "fmu", "path": str(path.resolve())}},
            "controller": {"name": "fixed", "step": step}}


def _feed_from_table(raw: dict[str, Any], system: System, csv_path: str | Path,
                     problems: list[Problem]) -> None:
    """Connect every column of the CSV to the FMU input of that name (model ``inputs``).

    The table steps first (Gauss–Seidel) and lands on its rows (time events), so the FMU's
    input over each step is interpolated through the table's fresh values: exact on every
    linear segment, as FMPy's inputs with their derivatives are.
    """
    from cosimstep.adapters.table import InputTable

    name = raw["name"]
    try:
        table = InputTable.from_csv(csv_path)
    except ConfigurationError as exc:
        problems.extend(exc.problems)
        return
    fmu = system.models[name]
    known = [p.name for p in fmu.inputs]
    for port in table.outputs:
        if port.name not in known:
            problems.append(Problem(f"{csv_path}: column {port.name}", f"'{name}' has no input "
                                    f"'{port.name}'", f"its inputs: {', '.join(known) or 'none'}"))
    if not problems:
        units = {p.name: p.unit for p in fmu.inputs}  # the CSV is in the inputs' own units
        table.outputs = tuple(replace(p, unit=units[p.name]) for p in table.outputs)
        source = "inputs" if name != "inputs" else "table"
        raw["master"] = {"name": "gauss-seidel", "order": [source, name]}
        system.add(source, table, f"{csv_path}")
        for port in table.outputs:
            system.connect(f"{source}.{port.name}", f"{name}.{port.name}", where=str(csv_path))


def _override(raw: dict[str, Any], overrides: dict[str, dict[str, Any]],
              problems: list[Problem]) -> None:
    """Apply command-line values to the file's tables (``model.name`` to that model's)."""
    models = raw.get("models", {})
    for table, values in overrides.items():
        for name, value in values.items():
            model, dot, key = name.rpartition(".")
            if not dot:
                raw.setdefault(table, {})[name] = value
            elif isinstance(models.get(model), dict):
                models[model].setdefault(table, {})[key] = value
            else:
                flag = "--param" if table == "parameters" else "--start"
                problems.append(Problem(f"{flag} {name}", f"no model '{model}'",
                                        f"models: {', '.join(models) or 'none'}"))


def _read_toml(path: Path) -> dict[str, Any]:
    src = str(path)
    if not path.exists():
        raise ConfigurationError([Problem(src, "file not found", "check the path")], src)
    try:
        return tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigurationError([Problem(src, f"not valid TOML: {exc}", "fix the syntax")],
                                 src) from exc


def _known_top(raw: dict[str, Any], loc: Callable[[str], str],
               problems: list[Problem]) -> dict[str, Any]:
    """``raw`` without top-level tables of the wrong shape; unknown keys reported."""
    for key, kind in (("models", dict), ("connections", list), ("parameter_changes", list)):
        if key in raw and not isinstance(raw[key], kind):
            shape, fix = ("table", f"[{key}.<name>]") if kind is dict else ("list", f"[[{key}]]")
            problems.append(Problem(loc(key), f"must be a {shape}", f"write {fix}"))
            raw = {k: v for k, v in raw.items() if k != key}
    for key in raw:
        if key not in KNOWN_TOP:
            problems.append(Problem(loc(key), "unknown top-level key",
                                    f"known keys: {', '.join(sorted(KNOWN_TOP))}"))
    return raw


def _build_system(raw: dict[str, Any], header: HeaderSection, changes: Changes, base_dir: Path,
                  loc: Callable[[str], str], problems: list[Problem], used: set[str]) -> System:
    """The models and connections of a TOML file, then the system-level checks."""
    system = System()
    refused = set()  # models already reported: their connections would only repeat that
    for name, body in raw.get("models", {}).items():
        where = loc(f"models.{name}")
        sec = parse(ModelSection, body, where, problems)
        model = None if sec is None else build_model(name, sec, header, changes, base_dir,
                                                      where, problems, used)
        if model is None:
            refused.add(name)
            continue
        try:
            system.add(name, model, where=where)
        except ValueError as exc:
            problems.append(Problem(where, str(exc), "rename the model"))
    for i, body in enumerate(raw.get("connections", [])):
        sec = parse(ConnectionSection, body, loc(f"connections[{i}]"), problems)
        ends = {str(end).partition(".")[0] for end in (sec.from_, sec.to)} if sec else set()
        if sec is not None and not ends & refused:
            system.connect(sec.from_, sec.to, sec.gain, sec.offset,
                           where=loc(f"connections[{i}] ({sec.from_} -> {sec.to})"),
                           round=sec.round)
    if raw.get("models"):
        problems.extend(system.problems())
    else:
        problems.append(Problem(loc("models"), "no models", "add [models.<name>] sections"))
    return system


__all__ = ["KNOWN_TOP", "ChangeSection", "ConnectionSection", "ModelSection", "SystemSpec",
           "load_system"]
