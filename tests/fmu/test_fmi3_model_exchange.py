"""FMI 3.0 model exchange and arrays with cosimstep's own C FMUs (issue 20, items 2, 4 and 7):

* `statespace3` — der(x) = A x + B u, y = C x + D u with 2-element array ports and 2 x 2 array
  parameters, offering model exchange and co-simulation; its exact solution is a matrix
  exponential.
* `bounce3` — a model-exchange-only ball: state events on the floor (h) and at the apex (v), an
  Int32 impact counter and a Boolean `falling` output, an Int32 input `kicks` that may change
  only in event mode, and terminateSimulation after `max_bounces` impacts.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sl

import cosimstep
from cosimstep.adapters.fmu import FmuSubModel
from cosimstep.adapters.fmu_me import MeSubModel
from cosimstep.adapters.fmu_open import open_fmu
from cosimstep.controllers import make_controller
from cosimstep.fmu.build import build_fmu

A = [[0.0, 1.0], [-9.0, -0.5]]
X0 = [0.5, 1.0]
G, E = 9.81, 0.7


@pytest.fixture(scope="module")
def ss(fmu_cache: Path) -> Path:
    return build_fmu("statespace3", cache=fmu_cache)


@pytest.fixture(scope="module")
def ball(fmu_cache: Path) -> Path:
    return build_fmu("bounce3", cache=fmu_cache)


def free_response(times: np.ndarray, a: list[list[float]], x0: list[float]) -> np.ndarray:
    return np.array([sl.expm(np.array(a) * t) @ x0 for t in times])


@pytest.mark.parametrize(("kind", "bound"), [("ME", 1e-7), ("CS", 1e-10)])
def test_array_parameters_and_ports(ss: Path, kind: str, bound: float) -> None:
    """A and x set as arrays; y[1], y[2] equal the matrix exponential's x(t). Model exchange
    is integrated by RK45 at rtol 1e-8 (measured 5.0e-9), co-simulation by the FMU's RK4 with
    1 ms steps (4.2e-12)."""
    model = open_fmu(ss, {"A": A, "x": X0}, kind=kind)
    assert [p.name for p in model.inputs] == ["u[1]", "u[2]", "k[1]", "k[2]"]
    assert [p.name for p in model.outputs] == ["y[1]", "y[2]", "k_out[1]", "k_out[2]"]
    assert isinstance(model, MeSubModel) == (kind == "ME")
    result = cosimstep.simulate(cosimstep.System().add("s", model), 2.0, cosimstep.Fixed(0.05))
    assert result.success, result.message
    exact = free_response(result.times, A, X0)
    error = max(np.max(np.abs(result["s.y[1]"] - exact[:, 0])),
                np.max(np.abs(result["s.y[2]"] - exact[:, 1])))
    assert error < bound
    # the array parameter was set: with the FMU's own A (0 1; -4 -0.4) the answer differs
    assert np.max(np.abs(exact - free_response(result.times, [[0, 1], [-4, -0.4]], X0))) > 0.1


def chain_toml(tmp_path: Path, interface: str) -> Path:
    """Two statespace3 FMUs in a TOML file, a's whole output array into b's input array."""
    text = f"""
until = 2.0
[models.a]
type = "fmu"
recipe = "statespace3"
interface = "{interface}"
start = {{ A = {A}, x = {X0} }}
[models.b]
type = "fmu"
recipe = "statespace3"
interface = "{interface}"
start = {{ x = [0.0, 0.0], B = [[1.0, 0.0], [0.0, 1.0]] }}
[[connections]]
from = "a.y"
to = "b.u"
[master]
name = "gauss-seidel"
extrapolation = 2
[controller]
name = "fixed"
step = 0.01
"""
    path = tmp_path / f"chain_{interface}.toml"
    path.write_text(text)
    return path


def test_a_whole_array_connection_from_toml_matches_the_monolithic_solution(
        tmp_path: Path) -> None:
    """a (free oscillator) drives b (der(x_b) = A_b x_b + x_a) through `a.y -> b.u`; both
    model exchange. Against the 4-state matrix exponential: measured 1.2e-6 at a step of
    0.01 s (b's inputs are a's outputs interpolated by quadratics in Gauss-Seidel order); an
    input left at zero would be off by 0.1."""
    loaded = cosimstep.load_system(chain_toml(tmp_path, "model-exchange"))
    assert {m.kind for m in loaded.system.models.values()} == {"ME"}
    assert [(c.source, c.target) for c in loaded.system.connections] == [("a.y", "b.u")]
    assert loaded.controller == {"name": "fixed", "step": 0.01}
    result = cosimstep.simulate(loaded.system, loaded.until, cosimstep.Fixed(0.01), loaded.master)
    assert result.success, result.message
    a_b = np.array([[0, 1], [-4, -0.4]])
    big = np.block([[np.array(A), np.zeros((2, 2))], [np.eye(2), a_b]])
    exact = free_response(result.times, big.tolist(), [*X0, 0.0, 0.0])
    error = max(np.max(np.abs(result[f"b.y[{i + 1}]"] - exact[:, 2 + i])) for i in range(2))
    assert error < 1e-5


def bounce_events(n: int) -> list[float]:
    """Impact times of the ball from h = 1 at rest (restitution E)."""
    t, speed, times = math.sqrt(2.0 / G), math.sqrt(2.0 * G), []
    for _ in range(n):
        times.append(t)
        speed *= E
        t += 2.0 * speed / G
    return times


def test_model_exchange_only_with_state_events_and_discrete_outputs(ball: Path) -> None:
    """Impacts at the analytic times (to 1e-9 s), the apex between them as an event too; the
    Int32 counter and the Boolean flag read at every point."""
    model = open_fmu(ball)
    assert isinstance(model, MeSubModel) and model.fmi_version == "3.0"
    assert [(p.name, p.kind) for p in model.outputs] == [
        ("h", "real"), ("v", "real"), ("bounces", "integer"), ("falling", "boolean"),
        ("tag_out", "binary")]
    assert [(p.name, p.kind) for p in model.inputs] == [("kicks", "integer"), ("tag", "binary")]
    result = cosimstep.simulate(cosimstep.System().add("b", model), 1.6, cosimstep.Fixed(0.01))
    assert result.success, result.message
    impacts = bounce_events(3)
    apexes = [(a + b) / 2 for a, b in itertools.pairwise(impacts)]
    assert np.allclose(model.events[:5], sorted(impacts + apexes), atol=1e-9, rtol=0)
    expected = np.searchsorted(impacts, result.times, side="right")
    assert np.array_equal(result["b.bounces"], expected.astype(float))
    # falling between an apex and the next impact (points at least 1 ms away from events)
    far = np.min(np.abs(result.times[:, None] - np.array(impacts + apexes)[None, :]), axis=1)
    edges = sorted(impacts + apexes)
    falling = np.searchsorted(edges, result.times) % 2 == 0  # before impact 1, after each apex
    assert np.array_equal(result["b.falling"][far > 1e-3], falling[far > 1e-3].astype(float))


def test_terminate_simulation_ends_the_run_ok(ball: Path) -> None:
    result = cosimstep.simulate(cosimstep.System().add("b", open_fmu(ball, {"max_bounces": 2})),
                                3.0, cosimstep.Fixed(0.01))
    assert result.status == "ok" and "terminateSimulation" in result.message
    second = bounce_events(2)[1]
    assert second - 0.01 < result.times[-1] <= second


def test_an_integer_input_is_set_in_event_mode(ball: Path, fmu_cache: Path) -> None:
    """The stair's counter (1, 2, ... on the half seconds; FMI 2.0 co-simulation) into the
    ball's `kicks` (FMI 3.0, settable only in event mode): every increment adds 2 m/s, so
    before the first impact v(t) = 2 counter(t) - g t exactly."""
    system = cosimstep.System()
    system.add("st", FmuSubModel(build_fmu("stair", cache=fmu_cache), {"period": 0.5}))
    system.add("b", open_fmu(ball))
    system.connect("st.counter", "b.kicks")
    result = cosimstep.simulate(system, 0.6, cosimstep.Fixed(0.01))
    assert result.success, result.message
    counter = 1 + np.floor(result.times / 0.5 + 1e-9)
    assert np.array_equal(result["st.counter"], counter)
    # The ball has a direct feedthrough (tag -> tag_out), so the master sets its inputs again
    # at every point before reading it: the kicks at t = 0 and 0.5 are in the points there.
    assert np.max(np.abs(result["b.v"] - (2.0 * counter - G * result.times))) < 1e-9


def test_adaptive_steps_roll_back_through_the_fmu_state(ball: Path) -> None:
    """Under `pc` rejected steps restore FMI 3.0 FMU states; the impacts stay exact."""
    model = open_fmu(ball)
    result = cosimstep.simulate(cosimstep.System().add("b", model), 1.2,
                                make_controller("pc", None, 1e-6))
    assert result.success, result.message
    impacts = bounce_events(2)
    found = [t for t in model.events if min(abs(t - i) for i in impacts) < 1e-6]
    assert np.allclose(found, impacts, atol=1e-9, rtol=0)
    assert result["b.bounces"][-1] == 2.0


@pytest.mark.parametrize("max_dt", [1e-3, 1e-4])
def test_co_simulation_event_mode_handles_events_at_their_time(fmu_cache: Path,
                                                               max_dt: float) -> None:
    """`bounce3_cs` declares hasEventMode: its doStep returns early at the internal RK4 step
    where an indicator changed sign, the adapter runs the event in event mode and finishes the
    communication step. The first impact is found within one internal step after the analytic
    time; later events inherit that delay (measured 1.4 and 2.4 internal steps), and the run
    equals FMPy's with event mode and early return."""
    import fmpy

    path = build_fmu("bounce3_cs", cache=fmu_cache)
    model = open_fmu(path, {"max_dt": max_dt})
    assert model.kind == "CS" and model.interface.hasEventMode
    result = cosimstep.simulate(cosimstep.System().add("b", model), 1.2, cosimstep.Fixed(0.01))
    assert result.success, result.message
    impacts = bounce_events(2)
    expected = sorted([*impacts, (impacts[0] + impacts[1]) / 2])
    assert len(model.events) == 3
    lag = np.array(model.events) - np.array(expected)
    assert 0.0 <= lag[0] <= max_dt * (1 + 1e-9)
    assert np.all(lag >= 0.0) and np.all(lag <= 3.0 * max_dt)
    assert result["b.bounces"][-1] == 2.0
    theirs = fmpy.simulate_fmu(str(path), stop_time=1.2, step_size=0.01, output_interval=0.01,
                               start_values={"max_dt": max_dt}, use_event_mode=True,
                               early_return_allowed=True)
    at = np.searchsorted(theirs["time"], result.times + 1e-9, side="right") - 1
    assert np.allclose(theirs["time"][at], result.times, atol=1e-12, rtol=0)
    for name in ("h", "v", "bounces"):
        assert np.max(np.abs(result[f"b.{name}"] - theirs[name][at])) < 1e-12


def test_co_simulation_event_mode_rolls_back(fmu_cache: Path) -> None:
    """Under `pc`, a rejected step restores the FMU state and forgets the events it found."""
    model = open_fmu(build_fmu("bounce3_cs", cache=fmu_cache), {"max_dt": 1e-4})
    result = cosimstep.simulate(cosimstep.System().add("b", model), 1.2,
                                make_controller("pc", None, 1e-5))
    assert result.success, result.message
    impacts = bounce_events(2)
    assert len(model.events) == 3 and result["b.bounces"][-1] == 2.0
    assert abs(model.events[0] - impacts[0]) <= 1e-4 and abs(model.events[2] - impacts[1]) <= 2e-4


@pytest.mark.parametrize("recipe", ["bounce3", "bounce3_cs"])
def test_binary_ports(fmu_cache: Path, recipe: str, tmp_path: Path) -> None:
    """FMI 3.0 Binary: `tag` (start 0xc0ffee, model description hex) passed to `tag_out`; one
    ball's `tag_out` into another's `tag` (set in event mode for model exchange, between steps
    for co-simulation) arrives at t = 0 through the feedthrough, and the store keeps the bytes.
    A Binary input refuses a number."""
    from cosimstep.store import read_run

    path = build_fmu(recipe, cache=fmu_cache)
    system = cosimstep.System()
    system.add("a", open_fmu(path, {"tag": b"\x01\x02\x03"})).add("b", open_fmu(path))
    system.add("c", open_fmu(path))
    system.connect("a.tag_out", "b.tag")
    result = cosimstep.simulate(system, 0.3, cosimstep.Fixed(0.1), store=tmp_path / "b.db")
    assert result.success, result.message
    assert result.text("b.tag_out") == [b"\x01\x02\x03"] * 4
    assert result.text("c.tag_out") == [b"\xc0\xff\xee"] * 4  # the start value
    assert read_run(tmp_path / "b.db").text("b.tag_out") == [b"\x01\x02\x03"] * 4
    system.connect("a.bounces", "c.tag")
    assert "an integer output feeds binary input 'c.tag'" in str(system.problems())


@pytest.mark.parametrize("kind", ["ME", "CS"])
def test_integer_array_ports(ss: Path, kind: str) -> None:
    """An Int32 array input k[2] (start "3 4") passed to the Int32 array output k_out[2]: one
    port per element, of kind integer, discrete; b's k = [7, 8] (a TOML-style list) reaches
    a through the whole-array connection `b.k_out -> a.k` at every point, also at t = 0
    (feedthrough)."""
    a, b = open_fmu(ss, kind=kind), open_fmu(ss, {"k": [7, 8]}, kind=kind)
    assert [(p.name, p.kind, p.start) for p in a.inputs][2:] == [
        ("k[1]", "integer", 3.0), ("k[2]", "integer", 4.0)]
    assert [(p.name, p.kind, p.discrete) for p in a.outputs][2:] == [
        ("k_out[1]", "integer", True), ("k_out[2]", "integer", True)]
    system = cosimstep.System().add("a", a).add("b", b).connect("b.k_out", "a.k")
    result = cosimstep.simulate(system, 0.3, cosimstep.Fixed(0.1))
    assert result.success, result.message
    assert list(result["a.k_out[1]"]) == [7.0] * 4 and list(result["a.k_out[2]"]) == [8.0] * 4
