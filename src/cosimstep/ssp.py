"""SSP 1.0 system structures (``.ssp``) as cosimstep systems.

An ``.ssp`` file is a zip archive holding ``SystemStructure.ssd`` and, usually, the FMUs under
``resources/``. :func:`load_ssp` checks every member name before anything is unpacked (absolute
names, ``..`` and symbolic links are refused), unpacks into a temporary folder that is removed
with the system, reads the SSD and returns the same :class:`~cosimstep.spec.SystemSpec` as a
TOML system file, so every master and controller runs it.

What is read from the SSD:

- ``ssd:Component`` (FMI 2.0 co-simulation FMUs): ``name``, ``source`` (a path inside the
  archive, ``cosimstep:recipe:<name>`` for an FMU built from cosimstep's own C sources on
  first use, see :mod:`cosimstep.fmu.build`, or ``cosimstep:export:<type>`` for a built-in
  sub-model exported with pythonfmu on first use) and its ``ssd:Connectors`` (name, kind, unit
  of ``ssc:Real``); a component of type ``application/x-cosimstep-model`` with source
  ``cosimstep:model:<type>`` is one of cosimstep's built-in sub-models itself (Python, or a
  discrete-event model), built as a ``[models.<name>]`` table of a system file would be (its
  own ``org.cosimstep`` annotation may give its internal ``solver``);
- ``ssd:Connection``: ``startElement.startConnector -> endElement.endConnector``, with
  ``ssc:LinearTransformation`` (factor, offset) and ``suppressUnitConversion``;
- ``ssd:Units``: unit definitions by SI base-unit exponents, factor and offset; a value moving
  between connectors of different units is converted (definitions from ``ssd:Units`` where both
  units are defined there, otherwise pint);
- ``ssd:ParameterBindings`` on components and on the system: inline
  ``ssd:ParameterValues/ssv:ParameterSet`` or ``source = "*.ssv"`` inside the archive, with an
  optional ``ssd:ParameterMapping`` (inline ``ssm:ParameterMapping`` or a ``.ssm`` source);
  the values become the FMUs' parameter and start-value overrides;
- ``ssd:DefaultExperiment``: ``stopTime`` is the run's end time;
- an ``ssc:Annotation`` of type ``org.cosimstep`` (see :data:`ANNOTATION_TYPE`): a TOML fragment
  with the same ``[reference]``, ``[parameters]``, ``[start]``, ``solver``,
  ``[[parameter_changes]]``, ``[master]`` and ``[controller]`` tables as a cosimstep system
  file — the monolithic reference, the built-in sub-models' shared values, the run defaults.

Every problem found is collected and raised together as one
:class:`~cosimstep.errors.ConfigurationError`.
"""

from __future__ import annotations

import math
import shutil
import stat
import tomllib
import weakref
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cosimstep.archive import escapes, new_folder, size_problems
from cosimstep.errors import ConfigurationError, Problem
from cosimstep.model_tables import ModelSection, build_model, parse_changes
from cosimstep.spec import Origin, SystemSpec, finish, parse_header
from cosimstep.system import System
from cosimstep.units import UnitError, conversion

SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
SSM = "http://ssp-standard.org/SSP1/SystemStructureParameterMapping"
COSIMSTEP = "urn:cosimstep:ssp:1"
NS = {"ssd": SSD, "ssc": SSC, "ssv": SSV, "ssm": SSM, "cosimstep": COSIMSTEP}
ANNOTATION_TYPE = "org.cosimstep"
SSD_NAME = "SystemStructure.ssd"
FMU_MIME = "application/x-fmu-sharedlibrary"
ANNOTATION_KEYS = {"name", "description", "until", "parameters", "start", "solver",
                   "parameter_changes", "master", "controller", "reference"}
MODEL_MIME = "application/x-cosimstep-model"
"""The type of a component that is one of cosimstep's built-in sub-models, not an FMU."""
MODEL_SCHEME = "cosimstep:model:"  # its source: cosimstep:model:<type>, e.g. ship.zone2
EXPORT_SCHEME = "cosimstep:export:"  # an FMU exported from a built-in type on first use
_BASE_UNITS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")

Affine = tuple[float, float]  # value -> a * value + b


@dataclass(frozen=True)
class SspUnit:
    """An ``ssc:Unit``: SI base-unit exponents plus ``si = factor * value + offset``."""

    name: str
    exponents: tuple[int, ...]
    factor: float = 1.0
    offset: float = 0.0


@dataclass
class Connector:
    name: str
    kind: str
    unit: str | None


@dataclass
class Component:
    name: str
    source: str
    type: str | None
    connectors: dict[str, Connector]
    bindings: list[ET.Element] = field(default_factory=list)
    implementation: str | None = None  # "co-simulation" | "model-exchange" | None (any)
    annotations: list[ET.Element] = field(default_factory=list)  # of type org.cosimstep


@dataclass
class Link:
    """One ``ssd:Connection``."""

    start: tuple[str, str]
    end: tuple[str, str]
    factor: float = 1.0
    offset: float = 0.0
    suppress_units: bool = False

    @property
    def label(self) -> str:
        return f"{'.'.join(self.start)} -> {'.'.join(self.end)}"


def _tag(ns: str, local: str) -> str:
    return f"{{{ns}}}{local}"


def unpack(path: Path, problems: list[Problem]) -> Path | None:
    """Check every member of an ``.ssp`` archive, then unpack it into a new temporary folder.

    Nothing is written when a member is refused: every refused member is recorded in
    ``problems`` and ``None`` returned. The caller removes the folder.
    """
    src = str(path)
    if not zipfile.is_zipfile(path):
        problems.append(Problem(src, "not a zip archive (an .ssp file is a zip archive)",
                                "give an .ssp archive holding SystemStructure.ssd"))
        return None
    try:
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
            for info in infos:
                if escapes(info.filename):
                    problems.append(Problem(f"{src}: {info.filename}", "archive member would "
                                            "unpack outside the SSP's folder (absolute path or "
                                            "'..')", "rebuild the archive with relative names"))
                elif stat.S_ISLNK(info.external_attr >> 16):
                    problems.append(Problem(f"{src}: {info.filename}", "archive member is a "
                                            "symbolic link", "store the file itself"))
            problems.extend(Problem(src, reason, "rebuild the archive without it, or raise the "
                                    "limit") for reason in size_problems(infos))
            names = {i.filename for i in infos}
            if SSD_NAME not in names:
                problems.append(Problem(src, f"no {SSD_NAME} at the top of the archive",
                                        f"add {SSD_NAME} (the system structure) to the archive"))
            if problems:
                return None
            folder = new_folder("ssp")
            try:
                zf.extractall(folder)
            except BaseException:
                shutil.rmtree(folder, ignore_errors=True)
                raise
    except (OSError, zipfile.BadZipFile) as exc:
        problems.append(Problem(src, f"corrupt archive: {exc}", "rebuild the .ssp archive"))
        return None
    return folder


def _float(elem: ET.Element, attr: str, default: float, where: str,
           problems: list[Problem]) -> float:
    text = elem.get(attr)
    if text is None:
        return default
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        problems.append(Problem(where, f"{attr}='{text}' is not a finite number",
                                "write a number"))
        return default
    return value


def _parse_xml(file: Path, where: str, problems: list[Problem]) -> ET.Element | None:
    try:
        return ET.parse(file).getroot()
    except (OSError, ET.ParseError) as exc:
        problems.append(Problem(where, f"not valid XML: {exc}", "fix the XML"))
        return None


def read_units(root: ET.Element, where: str, problems: list[Problem]) -> dict[str, SspUnit]:
    units = {}
    for unit in root.findall("ssd:Units/ssc:Unit", NS):
        name = unit.get("name", "")
        base = unit.find("ssc:BaseUnit", NS)
        loc = f"{where}: Units/{name}"
        if base is None:
            problems.append(Problem(loc, "unit without ssc:BaseUnit", "add <ssc:BaseUnit .../>"))
            continue
        exps = []
        for b in _BASE_UNITS:
            try:
                exps.append(int(base.get(b, "0")))
            except ValueError:
                problems.append(Problem(loc, f"exponent {b}='{base.get(b)}' is not an integer",
                                        "write an integer exponent"))
                exps.append(0)
        units[name] = SspUnit(name, tuple(exps), _float(base, "factor", 1.0, loc, problems),
                              _float(base, "offset", 0.0, loc, problems))
    return units


def _connector_conversion(source: str, target: str, units: dict[str, SspUnit]) -> Affine:
    """Between two connector units: by their ``ssd:Units`` definitions, else by pint."""
    if source == target:
        return 1.0, 0.0
    a, b = units.get(source), units.get(target)
    if a is not None and b is not None:
        if a.exponents != b.exponents:
            raise UnitError(f"cannot convert '{source}' to '{target}': different base units in "
                            "ssd:Units")
        # si = fa * x + oa = fb * y + ob
        return a.factor / b.factor, (a.offset - b.offset) / b.factor
    return conversion(source, target)


def _compose(*maps: Affine) -> Affine:
    """The affine map applying ``maps`` from left to right."""
    a, b = 1.0, 0.0
    for s, t in maps:
        a, b = s * a, s * b + t
    return a, b


_IMPLEMENTATIONS = {"any": None, "CoSimulation": "co-simulation",
                    "ModelExchange": "model-exchange"}
"""SSP's ssd:Component ``implementation`` as the TOML ``interface``."""


def _read_components(system: ET.Element, where: str,
                     problems: list[Problem]) -> dict[str, Component]:
    components: dict[str, Component] = {}
    elements = system.find("ssd:Elements", NS)
    for elem in list(elements) if elements is not None else []:
        name = elem.get("name", "")
        loc = f"{where}: Elements/{name or '?'}"
        if elem.tag != _tag(SSD, "Component"):
            problems.append(Problem(loc, f"{elem.tag.rpartition('}')[2]} elements are not "
                                    "supported", "flatten subsystems into one ssd:System of "
                                    "FMU components"))
            continue
        if not name or name in components:
            problems.append(Problem(loc, "component without a unique name",
                                    "give every component its own name"))
            continue
        connectors = {}
        for c in elem.findall("ssd:Connectors/ssd:Connector", NS):
            real = c.find("ssc:Real", NS)
            connectors[c.get("name", "")] = Connector(
                c.get("name", ""), c.get("kind", ""),
                real.get("unit") if real is not None else None)
        implementation = _IMPLEMENTATIONS.get(elem.get("implementation", "any"), "?")
        if implementation == "?":
            problems.append(Problem(f"{loc} implementation", f"implementation "
                                    f"'{elem.get('implementation')}' cannot be run",
                                    "use CoSimulation, ModelExchange or any"))
            implementation = None
        components[name] = Component(
            name, elem.get("source", ""), elem.get("type"), connectors,
            elem.findall("ssd:ParameterBindings/ssd:ParameterBinding", NS), implementation,
            [a for a in elem.findall("ssd:Annotations/ssc:Annotation", NS)
             if a.get("type") == ANNOTATION_TYPE])
    return components


def _read_links(system: ET.Element, where: str, problems: list[Problem]) -> list[Link]:
    links = []
    for i, c in enumerate(system.findall("ssd:Connections/ssd:Connection", NS)):
        loc = f"{where}: Connections[{i}]"
        link = Link((c.get("startElement", ""), c.get("startConnector", "")),
                    (c.get("endElement", ""), c.get("endConnector", "")),
                    suppress_units=c.get("suppressUnitConversion", "false") in ("true", "1"))
        lt = c.find("ssc:LinearTransformation", NS)
        if lt is not None:
            link.factor = _float(lt, "factor", 1.0, loc, problems)
            link.offset = _float(lt, "offset", 0.0, loc, problems)
        for other in ("BooleanMappingTransformation", "IntegerMappingTransformation",
                      "EnumerationMappingTransformation"):
            if c.find(f"ssc:{other}", NS) is not None:
                problems.append(Problem(f"{loc} ({link.label})", f"ssc:{other} is not "
                                        "supported", "connect Real connectors only"))
        links.append(link)
    return links


def read_ssd(folder: Path, where: str, problems: list[Problem]) -> dict[str, Any] | None:
    """Read ``SystemStructure.ssd`` from an unpacked SSP into plain data (no FMU is touched)."""
    root = _parse_xml(folder / SSD_NAME, where, problems)
    if root is None:
        return None
    if root.tag != _tag(SSD, "SystemStructureDescription"):
        problems.append(Problem(where, f"root element is {root.tag}, not "
                                "ssd:SystemStructureDescription",
                                f"use the SSP 1.0 namespace {SSD}"))
        return None
    system = root.find("ssd:System", NS)
    if system is None:
        problems.append(Problem(where, "no ssd:System element", "add the system"))
        return None
    components = _read_components(system, where, problems)
    links = _read_links(system, where, problems)
    experiment = root.find("ssd:DefaultExperiment", NS)
    stop = start = None
    if experiment is not None:
        loc = f"{where}: DefaultExperiment"
        start = _float(experiment, "startTime", 0.0, loc, problems)
        stop = _float(experiment, "stopTime", math.nan, loc, problems)
        if start != 0.0:
            problems.append(Problem(loc, f"startTime = {start}: runs start at 0",
                                    "use startTime = 0"))
        if math.isnan(stop):
            stop = None
    annotations = [a for a in (*root.findall("ssd:Annotations/ssc:Annotation", NS),
                               *system.findall("ssd:Annotations/ssc:Annotation", NS),
                               *root.findall("ssd:DefaultExperiment/ssd:Annotations/"
                                             "ssc:Annotation", NS))
                   if a.get("type") == ANNOTATION_TYPE]
    return {"name": root.get("name") or system.get("name"), "components": components,
            "links": links, "units": read_units(root, where, problems), "stop": stop,
            "bindings": system.findall("ssd:ParameterBindings/ssd:ParameterBinding", NS),
            "annotations": annotations}


def _parameter_values(binding: ET.Element, folder: Path, where: str,
                      problems: list[Problem]) -> dict[str, tuple[float, str | None]]:
    """``{name: (value, unit)}`` of one ``ssd:ParameterBinding`` after its mapping."""
    source = binding.get("source")
    if source is not None:
        loc = f"{where} source='{source}'"
        file = _member(source, folder, loc, problems)
        pset = _parse_xml(file, loc, problems) if file is not None else None
        if pset is not None and pset.tag != _tag(SSV, "ParameterSet"):
            problems.append(Problem(loc, "not an ssv:ParameterSet", f"use the namespace {SSV}"))
            pset = None
    else:
        loc = f"{where} (inline)"
        pset = binding.find("ssd:ParameterValues/ssv:ParameterSet", NS)
        if pset is None:
            problems.append(Problem(loc, "no ssd:ParameterValues/ssv:ParameterSet and no source",
                                    "give the values inline or source='resources/x.ssv'"))
    if pset is None:
        return {}
    values: dict[str, tuple[float, str | None]] = {}
    for p in pset.findall("ssv:Parameters/ssv:Parameter", NS):
        name = p.get("name", "")
        kind = next(iter(p), None)
        local = kind.tag.rpartition("}")[2] if kind is not None else "nothing"
        if kind is None or local not in ("Real", "Integer", "Boolean"):
            problems.append(Problem(f"{loc}: {name}", f"parameter of type {local} is not "
                                    "supported", "use ssv:Real, ssv:Integer or ssv:Boolean"))
            continue
        text = kind.get("value", "")
        if local == "Boolean":
            values[name] = (1.0 if text in ("true", "1") else 0.0, None)
        else:
            values[name] = (_float(kind, "value", math.nan, f"{loc}: {name}", problems),
                            kind.get("unit"))
    prefix = binding.get("prefix", "")
    values = {prefix + k: v for k, v in values.items() if not math.isnan(v[0])}
    return _apply_mapping(binding, values, folder, where, problems)


def _apply_mapping(binding: ET.Element, values: dict[str, tuple[float, str | None]],
                   folder: Path, where: str,
                   problems: list[Problem]) -> dict[str, tuple[float, str | None]]:
    mapping = binding.find("ssd:ParameterMapping", NS)
    if mapping is None:
        return values
    source = mapping.get("source")
    loc = f"{where} ParameterMapping"
    if source is not None:
        file = _member(source, folder, f"{loc} source='{source}'", problems)
        root = _parse_xml(file, loc, problems) if file is not None else None
    else:
        root = mapping.find("ssm:ParameterMapping", NS)
    if root is None:
        return values
    out = dict(values)
    for entry in root.findall("ssm:MappingEntry", NS):
        src, dst = entry.get("source", ""), entry.get("target", "")
        if src not in values:
            problems.append(Problem(f"{loc}: {src} -> {dst}", f"no parameter '{src}' in the "
                                    "bound values", "map names the parameter set defines"))
            continue
        value, unit = out.pop(src)
        lt = entry.find("ssc:LinearTransformation", NS)
        if lt is not None:
            value = (_float(lt, "factor", 1.0, loc, problems) * value
                     + _float(lt, "offset", 0.0, loc, problems))
        out[dst] = (value, unit)
    return out


def _member(name: str, folder: Path, where: str, problems: list[Problem]) -> Path | None:
    """A file inside the unpacked archive named by a relative URI."""
    if ":" in name.split("/")[0] or escapes(name):
        problems.append(Problem(where, f"'{name}' is not a relative path inside the archive",
                                "refer to files inside the .ssp, e.g. resources/model.fmu"))
        return None
    file = folder / name
    if not file.is_file():
        problems.append(Problem(where, f"'{name}' is not in the archive",
                                "add the file to the .ssp or fix the name"))
        return None
    return file


def _fmu_source(comp: Component, folder: Path, where: str, problems: list[Problem]) -> Path | None:
    from cosimstep.fmu.resolve import RECIPE_SCHEME, build_recipe

    if comp.type not in (None, FMU_MIME):
        problems.append(Problem(f"{where}.type", f"component type '{comp.type}' is not "
                                "supported", f"use FMUs ({FMU_MIME}) or built-in sub-models "
                                f"({MODEL_MIME}, source {MODEL_SCHEME}<type>)"))
        return None
    if comp.source.startswith(RECIPE_SCHEME):
        return build_recipe(comp.source[len(RECIPE_SCHEME):], f"{where}.source", problems)
    if not comp.source.endswith(".fmu"):
        problems.append(Problem(f"{where}.source", f"'{comp.source}' is not an .fmu",
                                f"use resources/<name>.fmu or {RECIPE_SCHEME}<name>"))
        return None
    return _member(comp.source, folder, f"{where}.source", problems)


def _annotation(annotations: list[ET.Element], where: str, problems: list[Problem],
                keys: frozenset[str] | set[str] = ANNOTATION_KEYS) -> dict[str, Any]:
    if len(annotations) > 1:
        problems.append(Problem(where, f"{len(annotations)} annotations of type "
                                f"'{ANNOTATION_TYPE}'", "keep one"))
    if not annotations:
        return {}
    settings = annotations[0].find("cosimstep:Settings", NS)
    if settings is None:
        problems.append(Problem(where, f"annotation '{ANNOTATION_TYPE}' without a "
                                f"<cosimstep:Settings xmlns:cosimstep='{COSIMSTEP}'> element",
                                "put the TOML settings inside that element"))
        return {}
    try:
        raw = tomllib.loads(settings.text or "")
    except tomllib.TOMLDecodeError as exc:
        problems.append(Problem(where, f"annotation settings are not valid TOML: {exc}",
                                "fix the TOML syntax"))
        return {}
    for key in raw:
        if key not in keys:
            problems.append(Problem(f"{where}.{key}", "unknown key in the cosimstep annotation",
                                    f"known keys: {', '.join(sorted(keys))}"))
    return {k: v for k, v in raw.items() if k in keys}


def load_ssp(path: str | Path, until: float | None = None,
             overrides: dict[str, dict[str, Any]] | None = None) -> SystemSpec:
    """Read an ``.ssp`` archive into a :class:`~cosimstep.spec.SystemSpec`.

    ``overrides``: shared values set from the command line, ``{"parameters": {NAME: value},
    "start": {...}}``, on top of the cosimstep annotation's ``[parameters]`` and ``[start]``
    (they reach the built-in sub-models and the reference, as in a system file).

    Raises :class:`ConfigurationError` listing every problem. The unpacked archive is removed
    when the returned system is garbage collected (or at exit), and at once on an error.
    """
    path = Path(path)
    src = str(path)
    if not path.is_file():
        raise ConfigurationError([Problem(src, "file not found", "check the path")], src)
    problems: list[Problem] = []
    folder = unpack(path, problems)
    if folder is None:
        raise ConfigurationError(problems, src)
    try:
        spec = _load_unpacked(path, folder, until, problems, overrides or {})
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        raise
    weakref.finalize(spec.system, shutil.rmtree, folder, True)
    return spec


def _load_unpacked(path: Path, folder: Path, until: float | None, problems: list[Problem],
                   overrides: dict[str, dict[str, Any]]) -> SystemSpec:
    src = str(path)
    where = f"{src}: {SSD_NAME}"
    ssd = read_ssd(folder, where, problems)
    if ssd is None:
        raise ConfigurationError(problems, src)
    components: dict[str, Component] = ssd["components"]
    if not components:
        problems.append(Problem(f"{where}: Elements", "no components",
                                "add ssd:Component elements"))
    aloc = f"{where}: Annotation {ANNOTATION_TYPE}"
    settings = _annotation(ssd["annotations"], aloc, problems)
    for table, values in overrides.items():
        settings[table] = {**settings.get(table, {}), **values}
    header = parse_header({k: v for k, v in settings.items()
                           if k in ("name", "description", "until", "parameters", "start",
                                    "solver")}, aloc, problems)
    changes = parse_changes(settings, lambda key: f"{aloc}.{key}", problems)
    system = System()
    _add_components(system, ssd, folder, where, problems, (header, changes))
    for i, link in enumerate(ssd["links"]):
        loc = f"{where}: Connections[{i}] ({link.label})"
        gain_offset = _link_gain(link, components, system, ssd["units"], loc, problems)
        if gain_offset is not None:
            system.connect(".".join(link.start), ".".join(link.end), *gain_offset, where=loc)
    if not problems:
        problems.extend(system.problems())
    # a reference maps system outputs: not worth checking against a system already refused
    broken = any(p.where.startswith((f"{where}: Connections", f"{where}: component"))
                 for p in problems)
    raw = {"format": "ssp", "ssd": ssd["name"],
           "components": {n: c.source for n, c in components.items()},
           "connections": [{"from": ".".join(c.start), "to": ".".join(c.end),
                            "factor": c.factor, "offset": c.offset} for c in ssd["links"]],
           "cosimstep": settings}
    origin = Origin(src, lambda key: f"{aloc}.{key}", ssd["name"] or path.stem, until,
                    ssd["stop"])
    return finish(settings, header, system, origin, problems, raw, changes=changes,
                  reference=not broken)


def _builtin(name: str, comp: Component, values: dict[str, tuple[float, str | None]],
             shared: tuple[Any, Any], folder: Path, where: str,
             problems: list[Problem]) -> Any:
    """A component naming a built-in type (``cosimstep:model:<type>``) or an FMU exported from
    one (``cosimstep:export:<type>``), built as the same ``[models.<name>]`` table of a system
    file would be: bound values are its parameters (start values where it reads them), and the
    annotation's shared ``parameters``, ``start``, ``solver`` and ``parameter_changes`` apply."""
    from cosimstep.models import REGISTRY

    header, changes = shared
    export = comp.source.startswith(EXPORT_SCHEME)
    wanted = FMU_MIME if export else MODEL_MIME
    if comp.type not in (None, wanted):
        problems.append(Problem(f"{where}.type", f"a component with source '{comp.source}' "
                                f"is of type {wanted}, not '{comp.type}'",
                                f"write type=\"{wanted}\""))
        return None
    kind_name = comp.source.split(":", 2)[2]
    kind = REGISTRY.get(kind_name)
    starts = kind.start if kind is not None and not export else ()
    parameters = {k: v for k, (v, _) in values.items() if k not in starts}
    start = {k: v for k, (v, _) in values.items() if k in starts}
    table = ({"type": "fmu", "export": kind_name} if export else {"type": kind_name})
    # the component's own annotation may give its internal solver, as a model table's `solver`
    own = _annotation(comp.annotations, f"{where} Annotation {ANNOTATION_TYPE}", problems,
                      {"solver"})
    sec = ModelSection(**table, parameters=parameters, start=start, solver=own.get("solver"))
    return build_model(name, sec, header, changes, folder, where, problems, set())


def _add_components(system: System, ssd: dict[str, Any], folder: Path, where: str,
                    problems: list[Problem], shared: tuple[Any, Any]) -> None:
    """One sub-model per component (an FMU, or a built-in type: :func:`_builtin`), with its
    parameter bindings: system-level bindings name "component.variable", component-level ones
    the component's own variables; a component's own binding wins."""
    from cosimstep.fmu.resolve import fmu_submodel

    components: dict[str, Component] = ssd["components"]
    system_values: dict[str, dict[str, tuple[float, str | None]]] = {}
    for i, b in enumerate(ssd["bindings"]):
        bloc = f"{where}: System ParameterBindings[{i}]"
        for name, value in _parameter_values(b, folder, bloc, problems).items():
            comp, dot, var = name.partition(".")
            if not dot or comp not in components:
                problems.append(Problem(f"{bloc}: {name}", "system-level parameters are named "
                                        "component.variable", f"components: "
                                        f"{', '.join(components) or 'none'}"))
                continue
            system_values.setdefault(comp, {})[var] = value
    for name, comp in components.items():
        loc = f"{where}: component {name}"
        builtin = comp.source.startswith((MODEL_SCHEME, EXPORT_SCHEME))
        fmu = None if builtin else _fmu_source(comp, folder, loc, problems)
        values = dict(system_values.get(name, {}))
        for i, b in enumerate(comp.bindings):
            values.update(_parameter_values(b, folder, f"{loc} ParameterBindings[{i}]",
                                            problems))
        if builtin:
            model = _builtin(name, comp, values, shared, folder, loc, problems)
        elif fmu is None:
            continue
        else:
            values = _in_fmu_units(values, fmu, loc, problems)
            model = fmu_submodel(name, fmu, {f"start.{k}": v for k, (v, _) in values.items()},
                                 f"{loc} parameter", problems, interface=comp.implementation)
        if model is None or not _check_connectors(comp, model, loc, problems):
            continue
        try:
            system.add(name, model, where=loc)
        except ValueError as exc:
            problems.append(Problem(loc, str(exc), "rename the component"))


def _in_fmu_units(values: dict[str, tuple[float, str | None]], fmu: Path, where: str,
                  problems: list[Problem]) -> dict[str, tuple[float, str | None]]:
    """Parameter values given with a unit, converted to the unit of the FMU variable."""
    if not any(unit for _, unit in values.values()):
        return values
    from cosimstep.adapters.fmu import SUPPORTED, check_fmu

    try:
        md = check_fmu(fmu, SUPPORTED)
    except ValueError:
        return values  # refused: fmu_submodel reports why
    declared = {v.name: v.unit or (v.declaredType.unit if v.declaredType is not None else None)
                for v in md.modelVariables}
    out = {}
    for name, (value, unit) in values.items():
        target = declared.get(name)
        if unit and target and unit != target:
            try:
                a, b = conversion(unit, target)
            except UnitError as exc:
                problems.append(Problem(f"{where} parameter {name}", f"unit mismatch: {exc}",
                                        f"give the value in {target}"))
                continue
            value = a * value + b
        out[name] = (value, target)
    return out


def _check_connectors(comp: Component, model: Any, where: str, problems: list[Problem]) -> bool:
    """Declared connectors must be variables (FMU) or ports (built-in) of a matching kind."""
    md = getattr(model, "model_description", None)
    if md is not None:
        kinds = {v.name: v.causality for v in md.modelVariables}
        owner = f"FMU variable of {model.path.name}"
    else:
        kinds = {**{p.name: "input" for p in model.inputs},
                 **{p.name: "output" for p in model.outputs}}
        owner = f"port of {comp.source}"
    ok = True
    for c in comp.connectors.values():
        loc = f"{where} connector {c.name}"
        if c.name not in kinds:
            problems.append(Problem(loc, f"no {owner.split(' of ')[0]} of this name",
                                    f"connectors name the {owner}s: {', '.join(kinds)}"))
            ok = False
        elif c.kind in ("input", "output") and kinds[c.name] != c.kind:
            problems.append(Problem(loc, f"declared kind '{c.kind}' but the {owner} is "
                                    f"'{kinds[c.name]}'", "match its causality"))
            ok = False
    return ok


def _port_unit(model: Any, port: str) -> str | None:
    for p in (*model.inputs, *model.outputs):
        if p.name == port:
            return p.unit
    return None


def _link_gain(link: Link, components: dict[str, Component], system: System,
               units: dict[str, SspUnit], where: str,
               problems: list[Problem]) -> tuple[float, float] | None:
    """The connection's ``(gain, offset)`` in :class:`System` terms.

    The value travels: source FMU unit -> source connector unit -> (unit conversion, unless
    suppressed) target connector unit -> linear transformation -> target FMU unit. ``System``
    itself converts source FMU unit -> target FMU unit, so the gain and offset returned make
    ``gain * that + offset`` equal the whole chain.
    """
    ends = []
    for (elem, conn), role in ((link.start, "start"), (link.end, "end")):
        comp = components.get(elem)
        if not elem:
            problems.append(Problem(where, f"{role}Element missing: connections to the system's "
                                    "own connectors are not supported",
                                    "connect component connectors directly"))
            return None
        if comp is None:
            problems.append(Problem(where, f"{role}Element '{elem}' is not a component",
                                    f"components: {', '.join(components) or 'none'}"))
            return None
        if comp.connectors and conn not in comp.connectors:
            problems.append(Problem(where, f"'{elem}' has no connector '{conn}'",
                                    f"its connectors: {', '.join(comp.connectors)}"))
            return None
        ends.append((comp, conn))
    (c1, n1), (c2, n2) = ends
    m1, m2 = system.models.get(c1.name), system.models.get(c2.name)
    if m1 is None or m2 is None:
        return None  # the component itself was refused; that problem is already listed
    u1, u2 = _port_unit(m1, n1), _port_unit(m2, n2)
    if u1 is None or u2 is None:
        return None  # System.problems names the unknown port
    cu1 = c1.connectors[n1].unit if n1 in c1.connectors else None
    cu2 = c2.connectors[n2].unit if n2 in c2.connectors else None
    cu1, cu2 = cu1 or u1, cu2 or u2
    try:
        chain = _compose(
            _across(u1, cu1, u1, units),
            (1.0, 0.0) if link.suppress_units else _connector_conversion(cu1, cu2, units),
            (link.factor, link.offset),
            _across(cu2, u2, u2, units))
        direct = conversion(u1, u2)
    except UnitError as exc:
        problems.append(Problem(where, f"unit mismatch: {exc}",
                                "connect connectors of compatible units, define the units in "
                                "ssd:Units, or set suppressUnitConversion"))
        return None
    gain = chain[0] / direct[0]
    return gain, chain[1] - gain * direct[1]


def _across(source: str, target: str, fmu_unit: str, units: dict[str, SspUnit]) -> Affine:
    """Between an FMU's unit and its connector's (either way); the same name is the same unit,
    and an FMU unit the SSD defines converts by the SSD's definitions."""
    if source == target:
        return 1.0, 0.0
    if fmu_unit in units:
        return _connector_conversion(source, target, units)
    return conversion(source, target)

