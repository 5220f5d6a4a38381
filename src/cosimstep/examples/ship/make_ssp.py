"""Write examples/ship_plant.ssp: the ship plant of examples/ship_plant_fmu.toml as SSP 1.0.

Components: the chiller as the C FMU (``cosimstep:recipe:ship_chiller``), zone 1 as the Python
zone exported with pythonfmu (``cosimstep:export:ship.zone1``), the rest cosimstep's built-in
sub-models (type ``application/x-cosimstep-model``, ``cosimstep:model:<type>``); all FMUs are
built on first use, so the archive holds no binary. The TOML file's shared parameters, parameter
change, master, controller and reference travel in the ``org.cosimstep`` annotation; the
network's implicit internal solver in its component's own annotation.

Run from the repository root: ``python examples/ship/make_ssp.py``.
"""

from __future__ import annotations

import tomllib
import zipfile
from pathlib import Path
from xml.sax.saxutils import quoteattr

import cosimstep

HERE = Path(__file__).resolve().parent.parent
SOURCE = HERE / "ship_plant_fmu.toml"
TARGET = HERE / "ship_plant.ssp"
FMU_MIME = "application/x-fmu-sharedlibrary"
MODEL_MIME = "application/x-cosimstep-model"
ANNOTATION = ('<ssd:Annotations><ssc:Annotation type="org.cosimstep"><cosimstep:Settings>\n'
              "{}\n        </cosimstep:Settings></ssc:Annotation></ssd:Annotations>")
SETTINGS = ("parameters", "parameter_changes", "master", "controller", "reference")


def _toml_value(value: object) -> str:
    if isinstance(value, dict):
        return "{ " + ", ".join(f'"{k}" = {_toml_value(v)}' for k, v in value.items()) + " }"
    if isinstance(value, str):
        return f'"{value}"'
    return repr(value)


def _settings(raw: dict) -> str:
    lines = [f"solver = {_toml_value(raw['solver'])}"]
    for key in SETTINGS:
        value = raw[key]
        if isinstance(value, list):
            for item in value:
                lines += ["", f"[[{key}]]"] + [f"{k} = {_toml_value(v)}" for k, v in item.items()]
        else:
            lines += ["", f"[{key}]"] + [f"{k} = {_toml_value(v)}" for k, v in value.items()]
    return "\n".join(lines)


def _component(name: str, table: dict, model: cosimstep.SubModel) -> str:
    if table["type"] == "fmu":
        kind, source = FMU_MIME, (f"cosimstep:recipe:{table['recipe']}" if "recipe" in table
                                  else f"cosimstep:export:{table['export']}")
    else:
        kind, source = MODEL_MIME, f"cosimstep:model:{table['type']}"
    connectors = [f'          <ssd:Connector name="{p.name}" kind="{role}"><ssc:Real/>'
                  "</ssd:Connector>"
                  for role, ports in (("input", model.inputs), ("output", model.outputs))
                  for p in ports]
    own = ""
    if "solver" in table:
        own = "\n        " + ANNOTATION.format(f"solver = {_toml_value(table['solver'])}")
    return (f'      <ssd:Component name="{name}" type="{kind}" source="{source}">\n'
            "        <ssd:Connectors>\n" + "\n".join(connectors) +
            f"\n        </ssd:Connectors>{own}\n      </ssd:Component>")


def main() -> None:
    raw = tomllib.loads(SOURCE.read_text())
    system = cosimstep.load_system(SOURCE).system
    components = "\n".join(_component(n, t, system.models[n]) for n, t in raw["models"].items())
    connections = "\n".join(
        '      <ssd:Connection startElement="{}" startConnector="{}" endElement="{}" '
        'endConnector="{}"/>'.format(*c["from"].split("."), *c["to"].split("."))
        for c in raw["connections"])
    ssd = f"""<?xml version="1.0" encoding="UTF-8"?>
<!-- Written by examples/ship/make_ssp.py from examples/ship_plant_fmu.toml: the ship plant with
     the chiller as a C FMU, zone 1 as an exported Python FMU and the rest built-in sub-models. -->
<ssd:SystemStructureDescription version="1.0" name="ship_plant_ssp"
    xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
    xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon"
    xmlns:cosimstep="urn:cosimstep:ssp:1">
  <ssd:System name="ship_plant" description={quoteattr(raw["description"])}>
    <ssd:Elements>
{components}
    </ssd:Elements>
    <ssd:Connections>
{connections}
    </ssd:Connections>
  </ssd:System>
  <ssd:DefaultExperiment startTime="0" stopTime="{raw['until']}">
    {ANNOTATION.format(_settings(raw))}
  </ssd:DefaultExperiment>
</ssd:SystemStructureDescription>
"""
    with zipfile.ZipFile(TARGET, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("SystemStructure.ssd", ssd)
    print(f"wrote {TARGET}")


if __name__ == "__main__":
    main()
