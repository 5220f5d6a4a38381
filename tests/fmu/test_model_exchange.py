"""Model-exchange FMUs integrated by cosimstep (issue 5): MeSubModel on the pendulum-bar ME FMUs
(no event indicators, no FMU state: rollback by continuous states and time) and the bouncing-ball
ME FMU (a state event on the floor, an input, and a time event), TOML systems with ME and FMI 3.0
FMUs, and refused FMUs."""

from __future__ import annotations

import math
import re
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import cosimstep
from cosimstep import ParameterSchedule
from cosimstep.adapters.fmu import FmuError, check_fmu
from cosimstep.adapters.fmu_me import MeSubModel
from cosimstep.adapters.fmu_open import open_fmu
from cosimstep.adapters.ode import SolveIvp
from cosimstep.controllers import make_controller
from cosimstep.fmu.build import build_fmu
from cosimstep.fmu.info import describe_fmu
from cosimstep.models.pendulum import bar, default_parameters

START = {"theta1": 0.4, "theta2": -0.3, "omega1": 0.0, "omega2": 0.0}
G, E = 9.81, 0.7


@pytest.fixture(scope="module")
def me_bars(fmu_cache: Path) -> dict[int, Path]:
    return {i: build_fmu(f"pendulum_bar{i}_me", cache=fmu_cache) for i in (1, 2)}


@pytest.fixture(scope="module")
def ball(fmu_cache: Path) -> Path:
    return build_fmu("bouncing_ball", cache=fmu_cache)


class CountingMe(MeSubModel):
    restores = 0

    def restore_state(self, token: Any) -> None:
        self.restores += 1
        super().restore_state(token)


def wire(system: cosimstep.System) -> cosimstep.System:
    system.connect("bar1.theta", "bar2.theta1").connect("bar1.omega", "bar2.omega1")
    system.connect("bar2.theta", "bar1.theta2").connect("bar2.omega", "bar1.omega2")
    return system


def me_pendulum(me_bars: dict[int, Path]) -> cosimstep.System:
    system = cosimstep.System()
    for i in (1, 2):
        system.add(f"bar{i}", CountingMe(me_bars[i]))
    return wire(system)


def python_pendulum(solver: Any) -> cosimstep.System:
    system = cosimstep.System()
    for i in (1, 2):
        system.add(f"bar{i}", bar(2, i, ParameterSchedule(default_parameters(2)), START, solver))
    return wire(system)


def test_me_bar_ports_and_capabilities(me_bars: dict[int, Path]) -> None:
    model = MeSubModel(me_bars[1])
    assert [(p.name, p.unit, p.start) for p in model.outputs] == [
        ("theta", "rad", 0.4), ("omega", "rad/s", 0.0)]
    assert [p.name for p in model.inputs] == ["theta2", "omega2"]
    caps = model.capabilities
    # no FMU state, but no events either: continuous states + time are the whole state
    assert caps.can_save_state and caps.provides_derivatives
    assert caps.max_input_derivative_order == 3 and not caps.has_direct_feedthrough
    assert model.solver == SolveIvp("RK45", 1e-8, 1e-10)  # as the Python sub-models
    with pytest.raises(ValueError, match="not a solve_ivp method"):
        open_fmu(me_bars[1], solver={"method": "rk4"})


@pytest.mark.parametrize("controller", ["fixed 0.01", "pc tol 1e-4"])
def test_me_pendulum_matches_python_with_the_same_solver(me_bars: dict[int, Path],
                                                         controller: str) -> None:
    """Same RK45 settings, same input polynomials: the same numbers (measured difference 0.0)."""

    def make() -> cosimstep.Controller:
        if controller == "fixed 0.01":
            return cosimstep.Fixed(0.01)
        return make_controller("pc", None, 1e-4)

    master = cosimstep.MasterOptions("gauss-seidel", 2)
    me_system = me_pendulum(me_bars)
    me = cosimstep.simulate(me_system, 1.0, make(), master)
    # carry=False: every step starts afresh, as the FMU's solve_ivp does
    py = cosimstep.simulate(python_pendulum(SolveIvp(carry=False)), 1.0, make(), master)
    assert me.success and py.success, (me.message, py.message)
    assert me.calls == py.calls and me.times.shape == py.times.shape
    assert np.max(np.abs(me.values - py.values)) <= 1e-12
    restores = [m.restores for m in me_system.models.values()]
    assert restores == [0, 0] if controller == "fixed 0.01" else min(restores) > 0


def test_me_pendulum_agrees_with_the_rk4_example(me_bars: dict[int, Path], examples: Path) -> None:
    """Against the example's RK4 bars (local step 1e-3): both solvers are far more accurate than
    the coupling, so they differ by their own errors only — RK45 at rtol 1e-8 on O(1) states and
    RK4 with Δt = 1e-3 (error ~ Δt^4). Measured 1.1e-10 over 2 s at ΔT = 0.01; bound rtol."""
    master = cosimstep.MasterOptions("gauss-seidel", 2)
    me = cosimstep.simulate(me_pendulum(me_bars), 2.0, cosimstep.Fixed(0.01), master)
    spec = cosimstep.load_system(examples / "double_pendulum_slow.toml")
    py = cosimstep.simulate(spec.system, 2.0, cosimstep.Fixed(0.01), master)
    assert me.success and py.success
    difference = np.max(np.abs(me.values - py.values))
    assert 0.0 < difference <= 1e-8, difference


def drop(ball: Path, start: dict[str, float] | None = None, h: float = 0.05,
         until: float = 2.0, floor: tuple[float, float] = (0.0, 0.0)) -> MeSubModel:
    """The ball dropped from h = 1 at rest; the floor at ``floor[0] + floor[1] t``."""
    model = MeSubModel(ball, start)
    model.initialize(0.0)
    t = 0.0
    while t < until - 1e-12:
        model.set_inputs(np.array([floor[0] + floor[1] * t]))
        if floor[1]:
            model.set_input_derivatives(np.array([[floor[1]]]))
        model.do_step(t, h)
        t += h
    return model


def bounce_times(n: int, t0: float = 0.0, h0: float = 1.0, v0: float = 0.0) -> list[float]:
    """Impact times of a ball thrown up at v0 from h0 at t0 (e = 0.7)."""
    t = t0 + (v0 + math.sqrt(v0 * v0 + 2 * G * h0)) / G
    v = math.sqrt(v0 * v0 + 2 * G * h0)
    times = [t]
    for _ in range(n - 1):
        v *= E
        t += 2 * v / G
        times.append(t)
    return times


def test_state_events_at_the_analytic_times(ball: Path) -> None:
    model = drop(ball)
    try:
        h, v, bounces = model.get_outputs()
    finally:
        model.terminate()
    expected = bounce_times(4)
    assert bounces == 4 and len(model.events) == 4
    # RK45 integrates the parabola exactly, so only root finding errs: measured <= 2.3e-16
    assert np.max(np.abs(np.array(model.events) - expected)) <= 1e-12
    assert model.capabilities.can_save_state and not model.capabilities.provides_derivatives
    # between bounces the ball is on its parabola
    tau = 2.0 - expected[-1]
    v4 = math.sqrt(2 * G) * E ** 4
    assert h == pytest.approx(v4 * tau - G * tau * tau / 2, abs=1e-9)
    assert v == pytest.approx(v4 - G * tau, abs=1e-9)


def test_rising_floor_as_an_input_polynomial(ball: Path) -> None:
    """The floor rises at 0.5 m/s, given as value + first derivative per step: the impact is at
    1 - g t²/2 = 0.5 t, inside one step of ΔT = 0.25."""
    model = drop(ball, h=0.25, until=0.5, floor=(0.0, 0.5))
    model.terminate()
    w = 0.5
    t_hit = (-w + math.sqrt(w * w + 2 * G)) / G
    assert len(model.events) == 1 and model.events[0] == pytest.approx(t_hit, abs=1e-12)


def test_time_event_and_rollback_across_events(ball: Path) -> None:
    """A kick of +3 m/s at t = 0.2 (a time event inside the step 0.15..0.3), then the bounce."""
    model = MeSubModel(ball, {"t_kick": 0.2, "kick": 3.0})
    model.initialize(0.0)
    try:
        t = 0.0
        for _ in range(2):
            model.set_inputs(np.array([0.0]))
            model.do_step(t, 0.15)
            t += 0.15
        token = model.save_state()
        for _ in range(8):
            model.do_step(t, 0.15)
            t += 0.15
        first, events = model.get_outputs(), list(model.events)
        model.restore_state(token)
        t = 0.3
        for _ in range(8):
            model.do_step(t, 0.15)
            t += 0.15
        assert np.array_equal(model.get_outputs(), first) and model.events == events
    finally:
        model.terminate()
    h1, v1 = 1.0 - G * 0.2**2 / 2, -G * 0.2 + 3.0
    hit = bounce_times(1, 0.2, h1, v1)[0]
    assert events[0] == 0.2 and events[1] == pytest.approx(hit, abs=1e-12)


def test_toml_systems_with_me_and_fmi3_fmus(tmp_path: Path) -> None:
    text = """
[models.bar1]
type = "fmu"
recipe = "pendulum_bar1_me"
solver = { method = "DOP853", rtol = 1e-9, atol = 1e-11 }
[models.bar2]
type = "fmu"
recipe = "pendulum_bar2_fmi3"
[[connections]]
from = "bar1.theta"
to = "bar2.theta1"
[[connections]]
from = "bar1.omega"
to = "bar2.omega1"
[[connections]]
from = "bar2.theta"
to = "bar1.theta2"
[[connections]]
from = "bar2.omega"
to = "bar1.omega2"
"""
    good = tmp_path / "mixed.toml"
    good.write_text(text)
    spec = cosimstep.load_system(good)
    assert type(spec.system.models["bar1"]).__name__ == "MeSubModel"
    assert spec.system.models["bar1"].solver == SolveIvp("DOP853", 1e-9, 1e-11)
    assert type(spec.system.models["bar2"]).__name__ == "Fmu3SubModel"
    result = cosimstep.simulate(spec.system, 0.2, cosimstep.Fixed(0.01))
    assert result.success and result.calls_total == 40
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('method = "DOP853"', 'method = "euler"')
                   .replace('recipe = "pendulum_bar2_fmi3"',
                            'recipe = "pendulum_bar2_fmi3"\nsolver = { method = "RK45" }'))
    with pytest.raises(cosimstep.ConfigurationError) as info:
        cosimstep.load_system(bad)
    message = str(info.value)
    assert "models.bar1.solver" in message and "not a solve_ivp method" in message
    assert "models.bar2.solver" in message and "only a model-exchange FMU takes a solver" in message


def _rewrite(source: Path, target: Path, md: Any) -> Path:
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(target, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if item.filename == "modelDescription.xml":
                data = md(data.decode()).encode()
            zout.writestr(item, data)
    return target


def test_refused_fmus(ball: Path, fmu_cache: Path, tmp_path: Path) -> None:
    fmi3 = build_fmu("pendulum_bar1_fmi3", cache=fmu_cache)
    fmi1 = tmp_path / "fmi1.fmu"
    with zipfile.ZipFile(fmi1, "w") as zf:
        zf.writestr("modelDescription.xml", '<?xml version="1.0"?>\n<fmiModelDescription '
                    'fmiVersion="1.0" modelName="old" modelIdentifier="old" guid="{1}" '
                    'numberOfContinuousStates="0" numberOfEventIndicators="0">'
                    "<ModelVariables/></fmiModelDescription>")
    fmi3_se = _rewrite(fmi3, tmp_path / "fmi3_se.fmu", lambda xml: re.sub(
        r"<CoSimulation.*?/>", '<ScheduledExecution modelIdentifier="pendulum_bar1_fmi3"/>',
        xml, flags=re.S))
    no_binary = tmp_path / "no_binary.fmu"
    with zipfile.ZipFile(fmi3) as zin, zipfile.ZipFile(no_binary, "w") as zout:
        for item in zin.infolist():
            if not item.filename.startswith("binaries/"):
                zout.writestr(item, zin.read(item))
    corrupt = tmp_path / "corrupt.fmu"
    corrupt.write_bytes(b"PK\x03\x04 not a zip")
    cases = [(fmi1, r"FMI 1\.0 is not supported \(cosimstep runs FMI 2\.0 co-simulation and FMI "
                    r"3\.0 co-simulation and FMI 2\.0 model exchange and FMI 3\.0 model "
                    r"exchange FMUs\)"),
             (fmi3_se, r"FMI 3\.0 scheduled execution only is not supported"),
             (no_binary, r"no binary for this platform \(binaries/x86_64-linux/"
                         r"pendulum_bar1_fmi3\.so is missing"),
             (corrupt, "not a zip archive")]
    for path, message in cases:
        with pytest.raises(ValueError, match=message) as info:
            open_fmu(path)
        assert str(path) in str(info.value)
    assert describe_fmu(fmi1)["runs_as"].startswith("not runnable: FMI 1.0 is not supported")
    assert describe_fmu(ball)["runs_as"].startswith("MeSubModel")
    assert describe_fmu(ball)["capabilities"]["ME"]["numberOfEventIndicators"] == 1
    check_fmu(ball, [("2.0", "ME")])  # accepted when asked for
    failing = MeSubModel(ball, {"e": 2.0}, instance_name="ball")
    with pytest.raises(FmuError, match=r"FMU 'ball' .*fmi2ExitInitializationMode returned error"
                                       r".*e must be in \[0, 1\]"):
        failing.initialize(0.0)
    assert failing._unzipped is None


@pytest.mark.parametrize("master", ["gauss-seidel", "multirate"])
def test_a_discrete_fmu_output_is_an_event_the_master_lands_on(ball: Path, master: str) -> None:
    """`bounces` is a discrete output (variability="discrete"): the master holds it and lands
    a point on each change, so its integral over 2 s is exact, Σ (2 - t_k)."""
    from helpers import Integrator

    system = cosimstep.System()
    system.add("ball", MeSubModel(ball))
    system.add("count", Integrator())
    system.connect("ball.bounces", "count.u")
    assert [p.discrete for p in system.models["ball"].outputs] == [False, False, True]
    result = cosimstep.simulate(system, 2.0, make_controller("pc", None, 1e-6),
                                cosimstep.MasterOptions(master, 2))
    assert result.success, result.message
    expected = bounce_times(4)
    times = [e.t for e in result.events]
    assert [(e.source, e.kind) for e in result.events] == [("ball", "change")] * 4
    # the FMU locates its own bounces to 2.3e-16 s; the master lands within 1e-12 s after
    assert np.max(np.abs(np.array(times) - expected)) < 1e-11
    integral = sum(2.0 - t for t in expected)
    assert result["count.x"][-1] == pytest.approx(integral, abs=1e-10)


def test_the_interface_is_chosen_in_the_system_file(tmp_path: Path) -> None:
    """`interface = "model-exchange"` runs the model-exchange-only ball; asking it for
    co-simulation is a configuration problem naming the key (exit 2)."""
    from click.testing import CliRunner

    from cosimstep.cli import main

    text = ('until = 0.5\n[models.ball]\ntype = "fmu"\nrecipe = "bouncing_ball"\n'
            'interface = "model-exchange"\n[controller]\nname = "fixed"\nstep = 0.01\n')
    (tmp_path / "me.toml").write_text(text)
    assert cosimstep.load_system(tmp_path / "me.toml").system.models["ball"].kind == "ME"
    (tmp_path / "cs.toml").write_text(text.replace("model-exchange", "co-simulation"))
    res = CliRunner().invoke(main, ["validate", str(tmp_path / "cs.toml")])
    assert res.exit_code == 2 and "models.ball.interface" in res.output
    assert "choose an interface the FMU offers" in res.output


def test_a_discrete_input_is_set_in_event_mode(fmu_cache: Path) -> None:
    """The `ramp` ME FMU (x' = rate) refuses a new `rate` (variability discrete) outside event
    mode, as the standard says; the adapter sends a changed value in event mode. Driven by the
    stair's counter (1, 2, 3, 4 on the half seconds), x(2) = 0.5 (1 + 2 + 3 + 4) = 5."""
    from cosimstep.adapters.fmu import FmuSubModel
    from cosimstep.adapters.fmu_open import open_fmu
    from cosimstep.fmu.build import build_fmu

    system = cosimstep.System()
    system.add("st", FmuSubModel(build_fmu("stair", cache=fmu_cache), {"period": 0.5}))
    system.add("r", open_fmu(build_fmu("ramp", cache=fmu_cache)))
    system.connect("st.counter", "r.rate")
    result = cosimstep.simulate(system, 2.0, cosimstep.Fixed(0.1),
                                cosimstep.MasterOptions("gauss-seidel", 0))
    assert result.success, result.message
    assert result["r.x"][-1] == pytest.approx(5.0, abs=1e-9)
    half = np.searchsorted(result.times, 1.0 - 1e-9)
    assert result["r.x"][half] == pytest.approx(1.5, abs=1e-9)  # 0.5 (1 + 2)
