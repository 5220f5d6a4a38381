"""The ship plant with FMUs (issue 17): the chiller compiled from C, zone 1 exported from Python,
and the same plant as an SSP archive whose components are FMUs and built-in sub-models."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import EXAMPLES
from cosimstep.adapters.fmu_open import open_fmu
from cosimstep.adapters.ode import ParameterSchedule, make_solver
from cosimstep.fmu.build import build_fmu
from cosimstep.models import ship
from cosimstep.sweep import prepare

pytest.importorskip("pythonfmu")
SHORT = {"t_hit": 1.0, "t_arm": 0.5}


def test_the_c_chiller_steps_as_the_python_chiller() -> None:
    fmu = open_fmu(build_fmu("ship_chiller"))
    python = ship.chiller(ParameterSchedule(ship.default_parameters()), {},
                          make_solver({"method": "rk4", "max_dt": 1.0}))
    u = np.array([23.0, 21.5, 24.0, 4.0, 5.0, 3.0])
    du = np.array([[0.01, -0.02, 0.005, 0.3, -0.1, 0.2], [1e-3, 0.0, -2e-3, 0.05, 0.0, -0.02]])
    t = 0.0
    for model in (fmu, python):
        model.initialize(0.0)
    token = fmu.save_state()
    for h in (0.5, 2.0, 3.7, 10.0):  # one to ten internal RK4 steps
        for model in (fmu, python):
            model.set_inputs(u)
            model.set_input_derivatives(du)
            model.do_step(t, h)
        t += h
        np.testing.assert_allclose(fmu.get_outputs(), python.get_outputs(), rtol=0, atol=1e-12)
    assert fmu.get_outputs()[0] != ship.THERMAL_START["Ts"]  # it moved
    fmu.restore_state(token)  # a rollback to the start
    assert fmu.get_outputs()[0] == ship.THERMAL_START["Ts"]


@pytest.mark.parametrize("source", ["ship_plant_fmu.toml", "ship_plant.ssp"])
def test_the_plant_with_fmus_matches_its_reference(source: str) -> None:
    from cosimstep.simulate import simulate

    spec, controller, master = prepare(str(EXAMPLES / source), SHORT,
                                       {"until": 2.0, "master": "multirate", "tol": 1e-3})
    kinds = {name: type(m).__name__ for name, m in spec.system.models.items()}
    assert kinds["chiller"] == kinds["zone1"] == "FmuSubModel"
    assert kinds["zone2"] == "OdeSubModel" and kinds["isolation"] == "Isolation"
    result = simulate(spec.system, spec.until, controller, master, reference=spec.reference,
                      progress=False)
    assert result.status == "ok", result.message
    assert [e.kind for e in result.events if e.source == "isolation"] == ["armed", "isolate"]
    assert result.error.max_scaled < 10 * 1e-3
