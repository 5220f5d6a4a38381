"""Export a built-in sub-model as an FMI 2.0 co-simulation FMU with pythonfmu (issue 5, item 5).

:func:`export_fmu` turns any kind in :data:`cosimstep.models.REGISTRY` (``"double_pendulum.bar1"``,
``"linear_coupled.fast"``...) into an ``.fmu`` that other co-simulation masters can run, so they
can be checked against cosimstep's reference problems.

The FMU mirrors the sub-model's ports: every input and output is a ``Real`` with the port's unit
(declared in ``UnitDefinitions``) and start value; outputs have ``initial="exact"`` so a master
can set the initial condition, and ``ModelStructure`` declares which inputs each output depends on
directly (none, for the ODE sub-models). The kind's parameters are ``fixed`` parameters. Inside,
``fmi2DoStep`` runs the very :class:`~cosimstep.adapters.ode.OdeSubModel` that the registry
builds, and ``fmi2GetFMUstate``/``fmi2SetFMUstate`` map to its ``save_state``/``restore_state``, so
the FMU declares ``canGetAndSetFMUstate`` and ``canSerializeFMUstate`` and supports rollback.

Requirements and limits of the exported FMU
-------------------------------------------
* pythonfmu ships one native library that runs the slave class in a Python interpreter: in a
  Python process (FMPy, cosimstep itself) the running interpreter; in a C/C++ tool the
  ``libpython`` the tool can load. **That Python must be able to import** ``cosimstep`` (with
  NumPy and SciPy); the FMU does not bundle it. Install cosimstep in that environment (for a C
  tool, point ``PYTHONHOME``/``PYTHONPATH`` at it). pythonfmu itself is bundled in the FMU.
* pythonfmu's runtime answers ``fmi2SetRealInputDerivatives`` and
  ``fmi2GetRealOutputDerivatives`` with an error, so the FMU declares
  ``canInterpolateInputs="false"`` and no output derivatives: inputs are held constant over a
  communication step, unlike the Python sub-model, which follows the input polynomial a master
  sets. At extrapolation order 0 the FMUs reproduce the Python sub-models exactly; at higher
  orders they do not (split double pendulum, Gauss–Seidel order 2, h = 0.001, 2 s: 3.7e-6 from
  the Python run), and the predictor–corrector controller, whose error estimate assumes the
  inputs follow the extrapolation, should be run at order 0 with them (tol 1e-4 and order 2 gave
  an error of 1e-3 against the reference, order 0 gave 1.1e-5).
* pythonfmu 0.7's runtime releases a reference to the slave module's namespace that it never
  took, once per ``fmi2Instantiate``; the generated script makes up for it
  (:func:`pin_module_dict`). Without that, the second instance in a process fails.
* The slave overrides pythonfmu's private state hooks (``_get_fmu_state``, ``_set_fmu_state``,
  ``_fmu_state_to_bytes``, ``_fmu_state_from_bytes``), hence the pin to pythonfmu 0.7.
* pythonfmu's ``fmi2GetFMUstate`` always creates a new state object; when a master passes an
  existing state to be overwritten (as FMI allows), the old one is not released until the
  instance ends, so very long runs with rollback grow memory by a few hundred bytes per saved
  state.
* Parameters are constant; the time-dependent parameter changes of a cosimstep system file are
  not part of the FMU.
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any
from xml.etree.ElementTree import Element, SubElement

import numpy as np

try:
    from pythonfmu import Fmi2Slave, FmuBuilder, Real
    from pythonfmu.enums import Fmi2Causality, Fmi2Initial, Fmi2Variability
except ImportError as _exc:  # pragma: no cover - depends on the environment
    raise ImportError("cosimstep.fmu.export needs pythonfmu: pip install 'cosimstep[export]'"
                      ) from _exc

from cosimstep.adapters.ode import ParameterSchedule, make_solver
from cosimstep.models import REGISTRY, ModelKind
from cosimstep.submodel import SubModel

DEFAULT_SOLVER: dict[str, Any] = {"method": "rk4", "max_dt": 1e-3}
"""The internal solver of an exported sub-model unless told otherwise (a system file's default)."""

_CONFIG_VERSION = 1  # bump when the configuration baked into a slave script changes meaning


# -- the slave that runs inside the FMU ----------------------------------------------------------
class _UnitReal(Real):
    """A pythonfmu ``Real`` that also writes the ``unit`` attribute (pythonfmu 0.7 has none)."""

    def __init__(self, name: str, unit: str | None = None, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.unit = unit

    def to_xml(self) -> Element:
        element = super().to_xml()
        real = element.find("Real")
        if self.unit and real is not None:
            real.set("unit", self.unit)
        return element


def _has_unit(unit: str) -> bool:
    return bool(unit) and unit != "1"


class CosimstepSlave(Fmi2Slave):
    """pythonfmu slave running one built-in cosimstep sub-model.

    Not used directly: :func:`export_fmu` writes a script with a subclass whose
    ``cosimstep_config`` names the kind, its parameters, start values, internal solver and which
    kind start value each port's start value sets.
    """

    cosimstep_config: Mapping[str, Any] = {}

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        config = self.cosimstep_config
        kind = _kind(config["kind"])
        self.description = f"cosimstep {kind.name}: {kind.description}"
        self._kind = kind
        self._values: dict[str, float] = {}
        self._start_of: dict[str, str] = dict(config["start_of"])
        self._model: SubModel | None = None
        self._t0 = 0.0
        proto = _build(kind, config["parameters"], config["start"], config["solver"])
        self._proto = proto
        self._input_names = [p.name for p in proto.inputs]
        self._output_names = [p.name for p in proto.outputs]
        for port in proto.outputs:
            exact = port.name in self._start_of
            self._add(port.name, 0.0 if port.start is None else port.start, port.unit,
                      port.description, causality=Fmi2Causality.output,
                      variability=Fmi2Variability.continuous,
                      initial=Fmi2Initial.exact if exact else None)
        for port in proto.inputs:
            self._add(port.name, 0.0 if port.start is None else port.start, port.unit,
                      port.description, causality=Fmi2Causality.input,
                      variability=Fmi2Variability.continuous)
        for name, value in config["parameters"].items():
            self._add(name, value, None, f"parameter {name} of {kind.name}",
                      causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                      initial=Fmi2Initial.exact)

    def _add(self, name: str, value: float, unit: str | None, description: str,
             **kwargs: Any) -> None:
        # Values live in a dictionary, not in attributes, so no port name can shadow a slave
        # attribute ("vars", "log"...).
        values = self._values
        values[name] = float(value)

        def getter() -> float:
            return values[name]

        def setter(v: float) -> None:
            values[name] = float(v)

        self.register_variable(
            _UnitReal(name, unit if unit and _has_unit(unit) else None,
                      description=description or None, getter=getter, setter=setter, **kwargs),
            nested=False)

    def to_xml(self, model_options: dict[str, str] | None = None) -> Element:
        root = super().to_xml(model_options or {})
        # pythonfmu writes no units and no output dependencies (which means "depends on every
        # input", i.e. direct feedthrough); add both.
        units = sorted({p.unit for p in (*self._proto.inputs, *self._proto.outputs)
                        if _has_unit(p.unit)})
        if units:
            definitions = Element("UnitDefinitions")
            for unit in units:
                SubElement(definitions, "Unit", {"name": unit})
            children = list(root)
            cosim = root.find("CoSimulation")
            root.insert(children.index(cosim) + 1 if cosim is not None else 0, definitions)
        index = {v.name: i + 1 for i, v in enumerate(self.vars.values())}
        feedthrough = self._proto.capabilities.feedthrough
        for unknown in root.findall("ModelStructure/Outputs/Unknown"):
            name = list(self.vars.values())[int(unknown.get("index", "0")) - 1].name
            deps = feedthrough.get(name, ())
            unknown.set("dependencies", " ".join(str(index[d]) for d in deps))
        return root

    # -- FMI calls -----------------------------------------------------------------------------
    def setup_experiment(self, start_time: float, stop_time: float | None,
                         tolerance: float | None) -> None:
        self._t0 = float(start_time)

    def exit_initialization_mode(self) -> None:
        config = self.cosimstep_config
        start = dict(config["start"])
        # Outputs first: a state's start value wins over an input that shares its name.
        for port in (*self._input_names, *self._output_names):
            if port in self._start_of:
                start[self._start_of[port]] = self._values[port]
        parameters = {name: self._values[name] for name in config["parameters"]}
        model = _build(self._kind, parameters, start, config["solver"])
        model.initialize(self._t0)
        self._model = model
        self._read_outputs()

    def do_step(self, current_time: float, step_size: float) -> bool:
        model = self._live()
        model.set_inputs(np.array([self._values[n] for n in self._input_names], dtype=float))
        model.do_step(current_time, step_size)
        self._read_outputs()
        return True

    def _read_outputs(self) -> None:
        for name, value in zip(self._output_names, self._live().get_outputs()):
            self._values[name] = float(value)

    def _live(self) -> SubModel:
        if self._model is None:
            raise RuntimeError(f"{self._kind.name}: the FMU is not initialized")
        return self._model

    def terminate(self) -> None:
        if self._model is not None:
            self._model.terminate()

    def _get_fmu_state(self) -> dict[str, Any]:
        token = self._model.save_state() if self._model is not None else None
        return {"values": dict(self._values), "model": token}

    def _set_fmu_state(self, state: dict[str, Any]) -> None:
        self._values.update(state["values"])
        if state["model"] is not None:
            self._live().restore_state(state["model"])

    @staticmethod
    def _fmu_state_to_bytes(state: dict[str, Any]) -> bytes:
        # JSON writes floats with repr, which reads back bit for bit.
        return json.dumps(_encode(state)).encode("utf-8")

    @staticmethod
    def _fmu_state_from_bytes(state: bytes) -> dict[str, Any]:
        return _decode(json.loads(state.decode("utf-8")))


def _encode(value: Any) -> Any:
    """Sub-model state tokens (tuples, arrays, floats) as JSON data, tagged to read back."""
    if isinstance(value, np.ndarray):
        return {"ndarray": value.tolist(), "dtype": str(value.dtype), "shape": list(value.shape)}
    if isinstance(value, tuple):
        return {"tuple": [_encode(v) for v in value]}
    if isinstance(value, list):
        return [_encode(v) for v in value]
    if isinstance(value, dict):
        return {"dict": {k: _encode(v) for k, v in value.items()}}
    if isinstance(value, np.generic):
        return value.item()
    return value


def _decode(value: Any) -> Any:
    if isinstance(value, list):
        return [_decode(v) for v in value]
    if isinstance(value, dict):
        if "ndarray" in value:
            return np.array(value["ndarray"], dtype=value["dtype"]).reshape(value["shape"])
        if "tuple" in value:
            return tuple(_decode(v) for v in value["tuple"])
        return {k: _decode(v) for k, v in value["dict"].items()}
    return value


_PINNED: list[dict[str, Any]] = []


def pin_module_dict(namespace: dict[str, Any]) -> None:
    """Keep one more reference to a slave module's namespace.

    pythonfmu 0.7's runtime, on every ``fmi2Instantiate``, imports the slave module (cached after
    the first time), executes the script's text once more with the module's namespace as globals,
    and then releases one reference to that namespace which it had only borrowed. The second
    instance in a process then finds a freed namespace ("module has no attribute ...", or a
    crash). The generated script calls this at module level, so each of those executions first
    adds the reference the runtime is going to release.
    """
    _PINNED.append(namespace)


# -- export ----------------------------------------------------------------------------------------
def _kind(name: str) -> ModelKind:
    kind = REGISTRY.get(name)
    if kind is None:
        raise ValueError(f"`kind` '{name}' is not a built-in sub-model; known kinds: "
                         f"{', '.join(sorted(REGISTRY))}")
    return kind


def _build(kind: ModelKind, parameters: Mapping[str, float], start: Mapping[str, float],
           solver: Mapping[str, Any]) -> SubModel:
    return kind.build(ParameterSchedule(dict(parameters)), dict(start), make_solver(solver))


def _checked(values: Mapping[str, Any] | None, known: Any, argument: str,
             kind: str) -> dict[str, float]:
    values = dict(values or {})
    problems = []
    for name, value in values.items():
        if name not in known:
            problems.append(f"'{name}' is not one of its {argument} ({', '.join(known)})")
        elif (isinstance(value, bool) or not isinstance(value, int | float)
              or not math.isfinite(value)):
            problems.append(f"'{name}' must be a finite number, got {value!r}")
    if problems:
        raise ValueError(f"`{argument}` for '{kind}': {'; '.join(problems)}")
    return {name: float(value) for name, value in values.items()}


def _start_map(kind: ModelKind, parameters: Mapping[str, float], start: Mapping[str, float],
               solver: Mapping[str, Any]) -> dict[str, str]:
    """Which of the kind's start values sets each port's start value.

    A builder reads start values by the system's names (``theta1``) while the ports have the
    sub-model's names (``theta``); moving one start value at a time shows which port follows it.
    """
    base = _build(kind, parameters, start, solver)
    before = {p.name: p.start for p in (*base.inputs, *base.outputs)}
    start_of: dict[str, str] = {}
    for name in kind.start:
        moved = _build(kind, parameters, {**start, name: start[name] + 1.0}, solver)
        for port in (*moved.inputs, *moved.outputs):
            if port.start != before[port.name]:
                start_of[port.name] = name
    return start_of


def export_fmu(kind: str, out: str | Path, parameters: Mapping[str, float] | None = None,
               start: Mapping[str, float] | None = None, *,
               solver: Mapping[str, Any] | None = None) -> Path:
    """Export the built-in sub-model ``kind`` as an FMI 2.0 co-simulation FMU.

    Parameters
    ----------
    kind:
        A name from :data:`cosimstep.models.REGISTRY`, e.g. ``"double_pendulum.bar1"``.
    out:
        The ``.fmu`` file to write, or a folder to write ``<kind with _ for .>.fmu`` into.
    parameters:
        Parameter values that replace the kind's defaults; they become the start values of the
        FMU's parameters (still settable before initialization).
    start:
        Start values by the kind's start names (``theta1``, ``omega2``...), as in a system file's
        ``[start]``; missing ones are the kind's own (``ModelKind.start_values``), else 0.
        They become the start values of the FMU's outputs and inputs.
    solver:
        The sub-model's internal solver, as in a system file (default
        ``{"method": "rk4", "max_dt": 1e-3}``).

    Returns
    -------
    Path
        The FMU written. Running it needs a Python that can import ``cosimstep`` (see the module
        documentation).

    Raises
    ------
    ValueError
        For an unknown kind, or unknown or non-numeric parameter or start names, or a bad solver.
    """
    model_kind = _kind(kind)
    params = {**model_kind.parameters,
              **_checked(parameters, model_kind.parameters, "parameters", kind)}
    given = _checked(start, model_kind.start, "start", kind)
    starts = {name: given.get(name, model_kind.start_values.get(name, 0.0))
              for name in model_kind.start}
    solver_spec = dict(DEFAULT_SOLVER if solver is None else solver)
    try:
        make_solver(solver_spec)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"`solver` {solver_spec!r}: {exc}") from exc
    config = {
        "version": _CONFIG_VERSION, "kind": kind, "parameters": params, "start": starts,
        "solver": solver_spec, "start_of": _start_map(model_kind, params, starts, solver_spec),
    }
    identifier = kind.replace(".", "_")
    if not identifier.isidentifier():
        raise ValueError(f"`kind` '{kind}' does not make a valid FMU model identifier")
    # The slave module is imported by name in the process that runs the FMU; a name unique to the
    # configuration keeps two exports of one kind from sharing a cached module.
    digest = hashlib.sha256(json.dumps(config, sort_keys=True).encode()).hexdigest()[:10]
    module = f"cosimstep_{identifier}_{digest}"
    out = Path(out)
    if out.suffix != ".fmu":
        out = out / f"{identifier}.fmu"
    out.parent.mkdir(parents=True, exist_ok=True)

    with tempfile.TemporaryDirectory(prefix="cosimstep-export-") as tmp:
        script = Path(tmp) / f"{module}.py"
        script.write_text(_SCRIPT.format(kind=kind, cls=identifier, config=repr(config)))
        saved_path = list(sys.path)
        try:
            built = FmuBuilder.build_FMU(script, dest=out, canGetAndSetFMUstate=True,
                                         canSerializeFMUstate=True)
        finally:
            # pythonfmu leaves the script's folder on sys.path and the module imported; the
            # module would hide the FMU's own copy of the script from a later load by name.
            sys.path[:] = saved_path
            sys.modules.pop(module, None)
    return Path(built)


_SCRIPT = '''\
"""pythonfmu slave for cosimstep's built-in sub-model '{kind}' (written by cosimstep.fmu.export).

Needs a Python that can import cosimstep, NumPy and SciPy.
"""

try:
    from cosimstep.fmu.export import CosimstepSlave, pin_module_dict
except ImportError as exc:
    raise ImportError(
        "this FMU runs cosimstep's sub-model '{kind}': install cosimstep in the Python that "
        "loads the FMU (pip install 'cosimstep[export]')") from exc

# pythonfmu's runtime runs this file once more per instance and then releases one reference to
# the module's namespace that it never took; keep one for it (see cosimstep.fmu.export).
pin_module_dict(globals())


class {cls}(CosimstepSlave):
    cosimstep_config = {config}
'''
