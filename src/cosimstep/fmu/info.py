"""What an FMU is, read from its ``modelDescription.xml`` (``cosimstep info MODEL.fmu``).

Unlike :func:`cosimstep.adapters.fmu.check_fmu`, any FMI version and kind is described, and
``runs_as`` says which cosimstep adapter runs it (FMI 2.0/3.0 co-simulation, or FMI 2.0/3.0
model exchange integrated by cosimstep) or why none can (FMI 1.0, FMI 3.0 scheduled execution,
another platform). Nothing is unpacked.
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from fmpy.model_description import (
        CoSimulation,
        ModelDescription,
        ModelExchange,
        ModelVariable,
    )

CAPABILITIES = ("canGetAndSetFMUstate", "canSerializeFMUstate", "canInterpolateInputs",
                "maxOutputDerivativeOrder", "canHandleVariableCommunicationStepSize",
                "providesDirectionalDerivative")
# FMI 3.0 spells the state capabilities with a capital S.
_FMI3_SPELLING = {"canGetAndSetFMUstate": "canGetAndSetFMUState",
                  "canSerializeFMUstate": "canSerializeFMUState"}
_ADAPTERS = {("2.0", "CS"): "FmuSubModel (FMI 2.0 co-simulation)",
             ("3.0", "CS"): "Fmu3SubModel (FMI 3.0 co-simulation)",
             ("2.0", "ME"): "MeSubModel (FMI 2.0 model exchange, integrated with solve_ivp)",
             ("3.0", "ME"): "MeSubModel (FMI 3.0 model exchange, integrated with solve_ivp)"}


def describe_fmu(path: str | Path) -> dict[str, Any]:
    """A JSON-ready description of an FMU; ``ValueError`` saying why a file is not one."""
    import fmpy

    path = Path(path)
    names = _archive_names(path)
    try:
        md = fmpy.read_model_description(str(path), validate=False)
    except Exception as exc:  # FMPy raises plain Exceptions for invalid descriptions
        raise ValueError(f"{path}: invalid modelDescription.xml: {exc}") from exc

    kinds = {kind: {"modelIdentifier": part.modelIdentifier,
                    "capabilities": _capabilities(md, kind, part)}
             for kind, part in (("CS", md.coSimulation), ("ME", md.modelExchange))
             if part is not None}
    platforms = _platforms(names)
    experiment = _experiment(md)
    variables = [_variable(v) for v in md.modelVariables]
    return {
        "file": str(path), "fmiVersion": md.fmiVersion, "kind": sorted(kinds),
        "modelName": md.modelName, "modelIdentifier": {k: p["modelIdentifier"]
                                                       for k, p in kinds.items()},
        "guid": md.guid, "description": md.description or "",
        "generationTool": md.generationTool or "", "platforms": platforms,
        "capabilities": {k: p["capabilities"] for k, p in kinds.items()},
        "defaultExperiment": experiment, "runs_as": _runs_as(path), "variables": variables,
    }


def _archive_names(path: Path) -> list[str]:
    """The archive's entry names, once it is known to be a safe zip with a model description;
    ``ValueError`` otherwise (before FMPy, whose own errors are less clear, reads it)."""
    from cosimstep.archive import escapes

    if not path.is_file():
        raise ValueError(f"{path}: no such file")
    if not zipfile.is_zipfile(path):
        raise ValueError(f"{path}: not a zip archive (an FMU is a zip file)")
    try:
        with zipfile.ZipFile(path) as zf:
            names = zf.namelist()
    except (OSError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: corrupt zip archive ({exc})") from exc
    unsafe = [n for n in names if escapes(n)]
    if unsafe:
        raise ValueError(f"{path}: archive entries would unpack outside the FMU's folder: "
                         f"{', '.join(unsafe)}")
    if "modelDescription.xml" not in names:
        raise ValueError(f"{path}: no modelDescription.xml at the top of the archive")
    return names


def _capabilities(md: ModelDescription, kind: str,
                  part: CoSimulation | ModelExchange) -> dict[str, Any]:
    """The capability flags of one interface (``kind`` "CS" or "ME"), under FMI 2.0's names
    whichever version spells them, and only those that apply to that kind."""
    caps = {}
    for cap in CAPABILITIES:
        value = getattr(part, cap, None)
        if value is None and cap in _FMI3_SPELLING:
            value = getattr(part, _FMI3_SPELLING[cap], None)
        caps[cap] = value
    if kind == "ME":
        caps["numberOfContinuousStates"] = md.numberOfContinuousStates
        caps["numberOfEventIndicators"] = md.numberOfEventIndicators
        caps["needsCompletedIntegratorStep"] = getattr(
            part, "needsCompletedIntegratorStep", None)
        for cap in ("maxOutputDerivativeOrder", "canInterpolateInputs",
                    "canHandleVariableCommunicationStepSize"):
            caps.pop(cap)  # co-simulation only
    return caps


def _platforms(names: list[str]) -> list[str]:
    """The platform folders under ``binaries/`` that hold at least one file."""
    return sorted({n.split("/")[1] for n in names
                   if n.startswith("binaries/") and n.count("/") >= 2 and n.split("/")[1]})


def _experiment(md: ModelDescription) -> dict[str, Any] | None:
    """The default experiment's settings, ``None`` when the FMU states none."""
    if md.defaultExperiment is None:
        return None
    de = md.defaultExperiment
    return {k: _number(getattr(de, k, None))
            for k in ("startTime", "stopTime", "tolerance", "stepSize")}


def _variable(v: ModelVariable) -> dict[str, Any]:
    """One model variable, its unit taken from its declared type when it has none itself."""
    unit = v.unit or (v.declaredType.unit if v.declaredType is not None else None)
    return {"name": v.name, "causality": v.causality,
            "variability": v.variability, "type": v.type,
            "start": _number(v.start), "unit": unit or "",
            "description": v.description or ""}


def _runs_as(path: Path) -> str:
    """The adapter that runs the FMU, or ``"not runnable: <reason>"``."""
    from cosimstep.adapters.fmu import SUPPORTED, check_fmu, fmu_interface

    try:
        md = check_fmu(path, SUPPORTED)
    except ValueError as exc:
        return f"not runnable: {str(exc).split(': ', 1)[-1]}"
    return _ADAPTERS[fmu_interface(md)]  # check_fmu accepted it: one of SUPPORTED


def _number(value: Any) -> Any:
    if value is None or isinstance(value, bool | int | float):
        return value
    try:
        return float(value)
    except (TypeError, ValueError):
        return str(value)


def format_info(info: dict[str, Any]) -> str:
    """The description as a human-readable report with a table of variables."""
    lines = _summary_lines(info)
    for kind, caps in info["capabilities"].items():
        lines.append(f"  capabilities ({kind})")
        lines += [f"    {k:40s} {v}" for k, v in caps.items() if v is not None]
    lines.append(f"  runs as          {info['runs_as']}")
    de = info["defaultExperiment"]
    if de:
        lines.append("  default experiment  " + ", ".join(f"{k} = {v}" for k, v in de.items()
                                                          if v is not None))
    lines.append(f"  variables ({len(info['variables'])})")
    lines += _variable_table(info["variables"])
    return "\n".join(lines)


def _summary_lines(info: dict[str, Any]) -> list[str]:
    """The report's head: what the FMU is, who made it and for which platforms."""
    lines = [f"{info['file']}",
             f"  FMI version      {info['fmiVersion']}",
             f"  kind             {' + '.join(info['kind']) or 'none'}",
             f"  model name       {info['modelName']}",
             "  identifier       " + ", ".join(f"{v} ({k})"
                                               for k, v in info["modelIdentifier"].items()),
             f"  generation tool  {info['generationTool'] or '-'}",
             f"  platforms        {', '.join(info['platforms']) or 'none (source only?)'}"]
    if info["description"]:
        lines.append(f"  description      {info['description']}")
    return lines


def _variable_table(variables: list[dict[str, Any]]) -> list[str]:
    """The variables as indented rows under a header, each column as wide as its longest cell."""
    rows = [("name", "causality", "variability", "type", "start", "unit")]
    rows += [(v["name"], v["causality"] or "", v["variability"] or "", v["type"],
              _start_text(v["start"]), v["unit"]) for v in variables]
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return ["    " + "  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]


def _start_text(start: Any) -> str:
    """A start value for the table: floats in ``%g`` so long decimals do not widen it."""
    if start is None:
        return ""
    return f"{start:g}" if isinstance(start, float) else str(start)
