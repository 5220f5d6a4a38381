"""SSP archives: the packaged double pendulum example (one FMU per bar, built from the repo's
C sources on first use) through the CLI, linear transformations and unit conversion on a small
hand-written two-bar SSD, and refusals of bad archives (exit 2, every problem listed)."""

from __future__ import annotations

import json
import math
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import cosimstep
from cosimstep.cli import main

TOLERANCE = 1e-9
MASTER = cosimstep.MasterOptions("gauss-seidel", 2)


def test_example_ssp_runs_from_the_cli(examples: Path, tmp_path: Path) -> None:
    ssp = examples / "fmu" / "double_pendulum.ssp"
    res = CliRunner().invoke(main, ["run", str(ssp), "--until", "1", "--json",
                                    "--out", str(tmp_path / "ssp.db")])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert out["status"] == "ok" and out["t_end"] == 1.0
    assert out["calls"] == {"bar1": 1000, "bar2": 1000}  # the annotation's fixed step 0.001
    assert set(out["error"]["per_variable"]) == {"bar1.theta", "bar1.omega", "bar2.theta",
                                                 "bar2.omega"}
    assert 0 < out["error"]["max_abs"] < 1e-6


def test_example_ssp_matches_python_pendulum(examples: Path) -> None:
    spec = cosimstep.load_system(examples / "fmu" / "double_pendulum.ssp")
    assert spec.until == 10.0 and spec.controller == {"name": "fixed", "step": 0.001}
    assert spec.master.name == "gauss-seidel" and spec.master.extrapolation == 2
    py = cosimstep.load_system(examples / "double_pendulum_slow.toml")
    a = cosimstep.simulate(spec.system, 2.0, cosimstep.Fixed(0.001), MASTER,
                           reference=spec.reference)
    b = cosimstep.simulate(py.system, 2.0, cosimstep.Fixed(0.001), MASTER,
                           reference=py.reference)
    assert a.success and b.success and a.names == b.names
    assert np.max(np.abs(a.values - b.values)) <= TOLERANCE
    assert a.error.per_variable == pytest.approx(b.error.per_variable, rel=1e-6)


# -- a small hand-written SSD ------------------------------------------------------------------

HEAD = """<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription version="1.0" name="two_bars"
    xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
    xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon"
    xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues"
    xmlns:cosimstep="urn:cosimstep:ssp:1">
<ssd:System name="two_bars"><ssd:Elements>
"""


def component(name: str, source: str, start: dict[str, float], extra: str = "") -> str:
    params = "".join(f'<ssv:Parameter name="{k}"><ssv:Real value="{v}"/></ssv:Parameter>'
                     for k, v in start.items())
    return (f'<ssd:Component name="{name}" source="{source}">{extra}<ssd:ParameterBindings>'
            f'<ssd:ParameterBinding><ssd:ParameterValues><ssv:ParameterSet version="1.0" '
            f'name="s"><ssv:Parameters>{params}</ssv:Parameters></ssv:ParameterSet>'
            '</ssd:ParameterValues></ssd:ParameterBinding>'
            '<ssd:ParameterBinding source="resources/lengths.ssv"/>'
            '</ssd:ParameterBindings></ssd:Component>')


def connection(a: str, b: str, lt: str = "") -> str:
    (e1, c1), (e2, c2) = a.split("."), b.split(".")
    return (f'<ssd:Connection startElement="{e1}" startConnector="{c1}" endElement="{e2}" '
            f'endConnector="{c2}">{lt}</ssd:Connection>')


LENGTHS = """<ssv:ParameterSet version="1.0" name="lengths"
    xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues"><ssv:Parameters>
<ssv:Parameter name="l1"><ssv:Real value="100" unit="cm"/></ssv:Parameter>
<ssv:Parameter name="l2"><ssv:Real value="1000" unit="mm"/></ssv:Parameter>
</ssv:Parameters></ssv:ParameterSet>"""


def with_unit(fmu: Path, out: Path, variable: str, unit: str) -> Path:
    """A copy of an FMU whose model description declares another unit for one variable."""
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(out, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "modelDescription.xml":
                text = data.decode()
                at = text.index(f'name="{variable}"')
                end = text.index("</ScalarVariable>", at)
                text = text[:at] + text[at:end].replace('unit="rad"', f'unit="{unit}"') \
                    + text[end:]
                text = text.replace("<UnitDefinitions>",
                                    '<UnitDefinitions><Unit name="deg"><BaseUnit rad="1" '
                                    'factor="0.017453292519943295"/></Unit>')
                data = text.encode()
            dst.writestr(item, data)
    return out


def write_ssp(path: Path, body: str, files: dict[str, Path | str]) -> Path:
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("SystemStructure.ssd", body)
        for name, content in files.items():
            if isinstance(content, Path):
                zf.write(content, name)
            else:
                zf.writestr(name, content)
    return path


START1 = {"theta": 0.4, "omega": 0.0, "theta2": -0.3, "omega2": 0.0}
START2 = {"theta": -0.3, "omega": 0.0, "theta1": 0.4, "omega1": 0.0}


def two_bars(tmp_path: Path, bar_fmus: dict[int, Path], theta_link: str,
             extra2: str = "") -> Path:
    """bar2's FMU declares its input theta1 in degrees (its C code still reads radians)."""
    deg = with_unit(bar_fmus[2], tmp_path / "bar2deg.fmu", "theta1", "deg")
    body = (HEAD + component("bar1", "resources/bar1.fmu", START1)
            + component("bar2", "resources/bar2.fmu", START2, extra2)
            + "</ssd:Elements><ssd:Connections>" + theta_link
            + connection("bar1.omega", "bar2.omega1") + connection("bar2.theta", "bar1.theta2")
            + connection("bar2.omega", "bar1.omega2")
            + "</ssd:Connections></ssd:System></ssd:SystemStructureDescription>")
    return write_ssp(tmp_path / "two_bars.ssp", body,
                     {"resources/bar1.fmu": bar_fmus[1], "resources/bar2.fmu": deg,
                      "resources/lengths.ssv": LENGTHS})


def test_unit_conversion_and_linear_transformation(tmp_path: Path, bar_fmus: dict[int, Path],
                                                   examples: Path) -> None:
    # rad -> deg by unit conversion, then factor pi/180 back: bar2 reads radians again, so the
    # system is the plain split pendulum (lengths 100 cm and 1000 mm bound in other units).
    lt = f'<ssc:LinearTransformation factor="{math.pi / 180!r}" offset="0"/>'
    spec = cosimstep.load_system(two_bars(tmp_path, bar_fmus,
                                          connection("bar1.theta", "bar2.theta1", lt)))
    link = spec.system.connections[0]
    assert (link.source, link.target) == ("bar1.theta", "bar2.theta1")
    assert link.gain == pytest.approx(math.pi / 180, rel=1e-15) and link.offset == 0.0
    compiled = spec.system.compile()
    k = compiled.names.index("bar2")
    assert compiled.a[k][0] == pytest.approx(1.0, abs=1e-15)  # conversion x transformation
    assert {n: v for n, (_, v) in spec.system.models["bar1"].start.items()}["l1"] == 1.0
    assert {n: v for n, (_, v) in spec.system.models["bar2"].start.items()}["l2"] == 1.0
    py = cosimstep.load_system(examples / "double_pendulum_slow.toml")
    a = cosimstep.simulate(spec.system, 1.0, cosimstep.Fixed(0.001), MASTER)
    b = cosimstep.simulate(py.system, 1.0, cosimstep.Fixed(0.001), MASTER)
    assert a.success and np.max(np.abs(a.values - b.values)) <= TOLERANCE

    # A transformation alone: target = factor * converted + offset, in the target's unit.
    lt = '<ssc:LinearTransformation factor="2" offset="0.5"/>'
    spec = cosimstep.load_system(two_bars(tmp_path, bar_fmus,
                                          connection("bar1.theta", "bar2.theta1", lt)))
    compiled = spec.system.compile()
    k = compiled.names.index("bar2")
    assert compiled.a[k][0] == pytest.approx(2 * 180 / math.pi, rel=1e-14)
    assert compiled.b[k][0] == pytest.approx(0.5, rel=1e-14)

    # suppressUnitConversion: the number passes unconverted, then the transformation.
    link = connection("bar1.theta", "bar2.theta1", lt).replace(
        "<ssd:Connection ", '<ssd:Connection suppressUnitConversion="true" ')
    compiled = cosimstep.load_system(two_bars(tmp_path, bar_fmus, link)).system.compile()
    assert compiled.a[k][0] == pytest.approx(2.0, rel=1e-14)


# -- refusals --------------------------------------------------------------------------------

def run_exit(path: Path) -> tuple[int, str]:
    res = CliRunner().invoke(main, ["run", str(path), "--json", "--out", str(path) + ".db"])
    return res.exit_code, res.output


def test_archive_without_ssd(tmp_path: Path) -> None:
    ssp = write_ssp(tmp_path / "x.ssp", "", {})
    with zipfile.ZipFile(ssp, "w") as zf:
        zf.writestr("resources/readme.txt", "no structure")
    code, out = run_exit(ssp)
    assert code == 2 and "no SystemStructure.ssd at the top of the archive" in out


def test_traversal_members_refused_before_unpacking(tmp_path: Path) -> None:
    ssp = tmp_path / "evil.ssp"
    with zipfile.ZipFile(ssp, "w") as zf:
        zf.writestr("SystemStructure.ssd", HEAD)
        zf.writestr("../evil.txt", "outside")
        zf.writestr("/abs.txt", "absolute")
    code, out = run_exit(ssp)
    assert code == 2 and "2 problem(s)" in out
    assert "../evil.txt: archive member would unpack outside" in out and "/abs.txt" in out
    assert not (tmp_path.parent / "evil.txt").exists()


def test_every_structure_problem_listed(tmp_path: Path, bar_fmus: dict[int, Path]) -> None:
    bad = (connection("bar1.theta", "bar2.thetaX") + connection("bar1.theta", "bar3.theta1"))
    ssp = two_bars(tmp_path, bar_fmus, bad)
    body = zipfile.ZipFile(ssp).read("SystemStructure.ssd").decode().replace(
        '<ssd:Component name="bar2" source="resources/bar2.fmu">',
        '<ssd:Component name="bar2" source="resources/bar2.fmu"><ssd:Connectors>'
        '<ssd:Connector name="theta1" kind="input"/><ssd:Connector name="theta" kind="output"/>'
        '<ssd:Connector name="omega" kind="output"/><ssd:Connector name="omega1" kind="input"/>'
        '<ssd:Connector name="nope" kind="input"/></ssd:Connectors>').replace(
        "resources/bar1.fmu", "resources/missing.fmu")
    broken = write_ssp(tmp_path / "broken.ssp", body, {
        "resources/bar2.fmu": tmp_path / "bar2deg.fmu", "resources/lengths.ssv": LENGTHS})
    code, out = run_exit(broken)
    assert code == 2, out
    for expected in ("component bar1.source: 'resources/missing.fmu' is not in the archive",
                     "connector nope: no FMU variable of this name",
                     "'bar2' has no connector 'thetaX'",
                     "endElement 'bar3' is not a component"):
        assert expected in out, out


def test_array_elements_are_set_from_ssv_parameters(tmp_path: Path, recipe_cache: Path) -> None:
    """SSV parameter values are scalars: `A[2,1]` and `x[1]` (FMI's structured names) set one
    element of an array each, the others keep the model description's start values. The FMI
    3.0 state-space FMU then follows the matrix exponential of A = [[0, 1], [-9, -0.4]]."""
    import scipy.linalg as sl

    from cosimstep.fmu.build import build_fmu

    params = {"A[2,1]": -9.0, "x[1]": 0.5, "x[2]": 1.0}
    values = "".join(f'<ssv:Parameter name="{k}"><ssv:Real value="{v}"/></ssv:Parameter>'
                     for k, v in params.items())
    body = (HEAD + '<ssd:Component name="ss" source="resources/ss.fmu"><ssd:ParameterBindings>'
            '<ssd:ParameterBinding><ssd:ParameterValues><ssv:ParameterSet version="1.0" '
            f'name="s"><ssv:Parameters>{values}</ssv:Parameters></ssv:ParameterSet>'
            "</ssd:ParameterValues></ssd:ParameterBinding></ssd:ParameterBindings>"
            "</ssd:Component></ssd:Elements></ssd:System></ssd:SystemStructureDescription>")
    path = write_ssp(tmp_path / "ss.ssp", body,
                     {"resources/ss.fmu": build_fmu("statespace3")})
    spec = cosimstep.load_system(path)
    result = cosimstep.simulate(spec.system, 1.0, cosimstep.Fixed(0.05))
    assert result.success, result.message
    a = np.array([[0.0, 1.0], [-9.0, -0.4]])
    exact = np.array([sl.expm(a * t) @ [0.5, 1.0] for t in result.times])
    assert np.max(np.abs(result["ss.y[1]"] - exact[:, 0])) < 1e-10
    bad = write_ssp(tmp_path / "bad.ssp", body.replace("A[2,1]", "A[3,1]"),
                    {"resources/ss.fmu": build_fmu("statespace3")})
    with pytest.raises(cosimstep.ConfigurationError, match=r"'A\[3,1\]' is not an element"):
        cosimstep.load_system(bad)


def test_the_component_implementation_chooses_the_interface(tmp_path: Path,
                                                            recipe_cache: Path) -> None:
    """ssd:Component implementation="ModelExchange" runs an FMU that offers both as model
    exchange (cosimstep integrates it), "CoSimulation" or none as co-simulation;
    "ScheduledExecution" is refused naming the attribute."""
    from cosimstep.fmu.build import build_fmu

    fmu = build_fmu("statespace3")

    def load(implementation: str) -> cosimstep.SystemSpec:
        attr = f' implementation="{implementation}"' if implementation else ""
        body = (HEAD + f'<ssd:Component name="ss" source="resources/ss.fmu"{attr}/>'
                "</ssd:Elements></ssd:System></ssd:SystemStructureDescription>")
        path = write_ssp(tmp_path / f"{implementation or 'any'}.ssp", body,
                         {"resources/ss.fmu": fmu})
        return cosimstep.load_system(path)

    assert load("ModelExchange").system.models["ss"].kind == "ME"
    assert load("CoSimulation").system.models["ss"].kind == "CS"
    assert load("").system.models["ss"].kind == "CS"
    with pytest.raises(cosimstep.ConfigurationError, match="implementation 'ScheduledExecution'"):
        load("ScheduledExecution")


# -- built-in sub-models as components ----------------------------------------------------------

def _builtin(name: str, kind: str, bound: dict[str, float], connectors: str = "",
             mime: str = "application/x-cosimstep-model") -> str:
    params = "".join(f'<ssv:Parameter name="{k}"><ssv:Real value="{v}"/></ssv:Parameter>'
                     for k, v in bound.items())
    return (f'<ssd:Component name="{name}" type="{mime}" source="cosimstep:model:{kind}">'
            f"<ssd:Connectors>{connectors}</ssd:Connectors><ssd:ParameterBindings>"
            '<ssd:ParameterBinding><ssd:ParameterValues><ssv:ParameterSet version="1.0" '
            f'name="s"><ssv:Parameters>{params}</ssv:Parameters></ssv:ParameterSet>'
            "</ssd:ParameterValues></ssd:ParameterBinding></ssd:ParameterBindings>"
            "</ssd:Component>")


SETTINGS = """<ssd:Annotations><ssc:Annotation type="org.cosimstep"><cosimstep:Settings>
solver = { method = "rk4", max_dt = 1e-4 }
[parameters]
lam = 100.0
[start]
u = 0.9000099990001
v = -9.99900009999
w = 1000.0
</cosimstep:Settings></ssc:Annotation></ssd:Annotations>"""


def _linear(tmp_path: Path, fast: str, slow: str) -> Path:
    body = (HEAD + fast + slow + "</ssd:Elements><ssd:Connections>"
            + connection("fast.u", "slow.u") + connection("slow.w", "fast.w")
            + "</ssd:Connections>" + SETTINGS + "</ssd:System></ssd:SystemStructureDescription>")
    return write_ssp(tmp_path / "linear.ssp", body, {})


def test_built_in_components_run_as_their_toml_tables(tmp_path: Path, examples: Path) -> None:
    # the annotation's shared lam and start values, and a bound value (slow's own lam, unused
    # by its equation but a parameter of its kind), reach the sub-models as in the TOML file
    ssp = _linear(tmp_path, _builtin("fast", "linear_coupled.fast", {},
                                     '<ssd:Connector name="u" kind="output"/>'
                                     '<ssd:Connector name="w" kind="input"/>'),
                  _builtin("slow", "linear_coupled.slow", {"lam": 100.0}))
    spec = cosimstep.load_system(ssp)
    toml = cosimstep.load_system(examples / "linear_coupled.toml")
    a = cosimstep.simulate(spec.system, 0.2, cosimstep.Fixed(1e-3), MASTER)
    b = cosimstep.simulate(toml.system, 0.2, cosimstep.Fixed(1e-3), MASTER)
    assert a.success and a.names == b.names
    np.testing.assert_array_equal(a.values, b.values)
    # a shared value from the command line reaches them too
    other = cosimstep.load_system(ssp, overrides={"parameters": {"lam": 50.0}})
    c = cosimstep.simulate(other.system, 0.2, cosimstep.Fixed(1e-3), MASTER)
    assert not np.allclose(c.values, a.values)


def test_bad_built_in_components_are_all_listed(tmp_path: Path) -> None:
    ssp = _linear(tmp_path, _builtin("fast", "linear_coupled.fastest", {}),
                  _builtin("slow", "linear_coupled.slow", {"tau": 1.0},
                           '<ssd:Connector name="x" kind="input"/>'))
    code, out = run_exit(ssp)
    assert code == 2, out
    for expected in ("component fast.type: unknown model type 'linear_coupled.fastest'",
                     "component slow.parameters.tau: 'linear_coupled.slow' has no parameter",
                     "'slow' has no connector 'u' (fix: its connectors: x)"):
        assert expected in out, out
    wrong = _linear(tmp_path, _builtin("fast", "linear_coupled.fast", {},
                                       mime="application/x-fmu-sharedlibrary"),
                    _builtin("slow", "linear_coupled.slow", {}))
    code, out = run_exit(wrong)
    assert code == 2 and "is of type application/x-cosimstep-model" in out, out
