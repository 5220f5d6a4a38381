"""Integer and boolean FMU variables as ports (issue 20, item 1, FMI 2.0): cosimstep's own C
FMUs `stair` (an integer counter stepping up at every multiple of `period`, a boolean true while
it is odd; no inputs, no real outputs) and `echo` (integer and boolean inputs passed straight to
outputs, and the integral of the integer input as a real output)."""

from __future__ import annotations

from pathlib import Path

import fmpy
import numpy as np
import pytest

import cosimstep
from cosimstep.adapters.fmu import FmuSubModel
from cosimstep.controllers import make_controller
from cosimstep.fmu.build import build_fmu
from cosimstep.symbols import SYMBOLS


@pytest.fixture(scope="module")
def fmus(fmu_cache: Path) -> dict[str, Path]:
    return {name: build_fmu(name, cache=fmu_cache) for name in ("stair", "echo")}


def stair_into_echo(fmus: dict[str, Path], period: float = 0.5) -> cosimstep.System:
    system = cosimstep.System()
    system.add("st", FmuSubModel(fmus["stair"], {"period": period}))
    system.add("ec", FmuSubModel(fmus["echo"]))
    system.connect("st.counter", "ec.n").connect("st.odd", "ec.b").connect("st.word", "ec.s")
    return system


def test_ports_have_their_kinds(fmus: dict[str, Path]) -> None:
    st, ec = FmuSubModel(fmus["stair"]), FmuSubModel(fmus["echo"])
    assert st.inputs == () and [(p.name, p.kind, p.discrete, p.start) for p in st.outputs] == [
        ("counter", "integer", True, 1.0), ("odd", "boolean", True, 1.0),
        ("word", "string", True, SYMBOLS.code("odd"))]
    assert [(p.name, p.kind) for p in ec.inputs] == [("n", "integer"), ("b", "boolean"),
                                                     ("s", "string")]
    assert [(p.name, p.kind, p.discrete, p.unit) for p in ec.outputs] == [
        ("x", "real", False, "1"), ("n_out", "integer", True, "1"),
        ("b_out", "boolean", True, "1"), ("s_out", "string", True, "text")]
    assert ec.capabilities.feedthrough == {"x": (), "n_out": ("n",), "b_out": ("b",),
                                           "s_out": ("s",)}


def test_a_stair_alone_equals_fmpy(fmus: dict[str, Path]) -> None:
    """No inputs and no real outputs: it runs, and its values are FMPy's at every point."""
    system = cosimstep.System().add("st", FmuSubModel(fmus["stair"]))
    result = cosimstep.simulate(system, 3.0, cosimstep.Fixed(0.01))
    assert result.success, result.message
    theirs = fmpy.simulate_fmu(str(fmus["stair"]), stop_time=3.0, step_size=0.01,
                               output_interval=0.01)
    assert np.array_equal(result["st.counter"], theirs["counter"].astype(float))
    assert np.array_equal(result["st.odd"], theirs["odd"].astype(float))


@pytest.mark.parametrize("master", ["gauss-seidel", "jacobi"])
def test_integer_steps_arrive_at_the_event_times(fmus: dict[str, Path], master: str) -> None:
    """The counter feeds an integer input through a direct-feedthrough FMU: the new value is
    there at the event time itself (the feedthrough is settled at every point), and the real
    output integrating it is exact: x(t) = sum of the counter over the steps."""
    result = cosimstep.simulate(stair_into_echo(fmus), 3.0, cosimstep.Fixed(0.01),
                                cosimstep.MasterOptions(master, 2))
    assert result.success, result.message
    t = result.times
    counter = 1 + np.floor(t / 0.5 + 1e-12)
    assert np.array_equal(result["st.counter"], counter)
    assert np.array_equal(result["ec.n_out"], counter)  # not one step late
    assert np.array_equal(result["ec.b_out"], counter % 2)
    words = ["odd" if c % 2 else "even" for c in counter]
    assert result.text("st.word") == words and result.text("ec.s_out") == words
    # x(t) = integral of the counter held over each step (1 on [0, 0.5), 2 on [0.5, 1), ...)
    steps = np.arange(len(t) - 1)
    x = np.concatenate([[0.0], np.cumsum(0.01 * (1 + np.floor(steps * 0.01 / 0.5 + 1e-12)))])
    assert np.max(np.abs(result["ec.x"] - x)) < 1e-12


def test_an_adaptive_run_lands_on_the_integer_steps(fmus: dict[str, Path]) -> None:
    """Under `pc` a change of the counter inside a step is a state event, located by rollback
    to within 1e-12 s of the FMU's own event times (multiples of 0.5 s)."""
    result = cosimstep.simulate(stair_into_echo(fmus), 3.0, make_controller("pc", None, 1e-4),
                                max_calls=2000)
    assert result.success, result.message
    changes = sorted({e.t for e in result.events if e.source == "st"})
    assert np.allclose(changes, [0.5, 1.0, 1.5, 2.0, 2.5, 3.0], rtol=0, atol=1e-11)
    assert not any(e.late for e in result.events)
    assert result.calls_total < 1000  # measured 700


def test_connections_are_type_checked(fmus: dict[str, Path], examples: Path) -> None:
    spec = cosimstep.load_system(examples / "double_pendulum_slow.toml")
    system = spec.system
    system.add("ec", FmuSubModel(fmus["echo"]))
    system.add("st", FmuSubModel(fmus["stair"]))
    system.connect("bar1.theta", "ec.n")  # real into integer: refused
    system.connect("st.counter", "ec.b", gain=2.0)  # scaled into a boolean: refused
    system.connect("st.counter", "ec.s")  # a number into a string: refused, even rounded
    problems = [str(p) for p in system.problems()]
    assert len(problems) == 3
    assert "a real output feeds integer input 'ec.n'" in problems[0]
    assert "integer output scaled by the connection feeds boolean input 'ec.b'" in problems[1]
    assert "an integer output feeds string input 'ec.s'" in problems[2]
    assert all("round = true" in p for p in problems[:2])
    assert "connect a string output, without gain, offset or rounding" in problems[2]


def test_a_declared_rounding_feeds_an_integer_input(fmus: dict[str, Path],
                                                    examples: Path) -> None:
    """`round = true`: ten times bar 1's angle, rounded, drives the echo's integer input."""
    spec = cosimstep.load_system(examples / "double_pendulum_slow.toml")
    system = spec.system
    system.add("ec", FmuSubModel(fmus["echo"]))
    system.connect("bar1.theta", "ec.n", gain=10.0, round=True)
    assert system.problems() == []
    result = cosimstep.simulate(system, 2.0, cosimstep.Fixed(0.01),
                                cosimstep.MasterOptions("gauss-seidel", 0))
    assert result.success, result.message
    assert np.array_equal(result["ec.n_out"], np.round(10 * result["bar1.theta"]))


def test_the_system_file_takes_the_rounding_and_the_recipes(tmp_path: Path) -> None:
    from click.testing import CliRunner

    from cosimstep.cli import main

    text = """until = 3.0
[models.st]
type = "fmu"
recipe = "stair"
parameters = { period = 0.5 }
[models.ec]
type = "fmu"
recipe = "echo"
[[connections]]
from = "st.counter"
to = "ec.n"
[[connections]]
from = "st.odd"
to = "ec.b"
[controller]
name = "fixed"
step = 0.01
"""
    (tmp_path / "s.toml").write_text(text)
    res = CliRunner().invoke(main, ["run", str(tmp_path / "s.toml"), "--no-store", "--json"])
    assert res.exit_code == 0, res.output
    bad = text.replace('from = "st.odd"', 'from = "ec.x"')
    (tmp_path / "bad.toml").write_text(bad)
    res = CliRunner().invoke(main, ["validate", str(tmp_path / "bad.toml")])
    assert res.exit_code == 2 and "a real output feeds boolean input 'ec.b'" in res.output
    (tmp_path / "ok.toml").write_text(bad.replace('to = "ec.b"', 'to = "ec.b"\nround = true'))
    res = CliRunner().invoke(main, ["validate", str(tmp_path / "ok.toml")])
    assert res.exit_code == 0, res.output


def test_string_and_boolean_parameters_from_the_system_file(tmp_path: Path) -> None:
    """A String parameter takes a TOML string (and refuses a number, exit 2); the FMU holds
    what was set (read back with fmi2GetString)."""
    from click.testing import CliRunner

    from cosimstep.cli import main

    text = ('until = 1.0\n[models.st]\ntype = "fmu"\nrecipe = "stair"\n'
            'parameters = { period = 0.25, label = "a name" }\n'
            '[controller]\nname = "fixed"\nstep = 0.1\n')
    (tmp_path / "s.toml").write_text(text)
    model = cosimstep.load_system(tmp_path / "s.toml").system.models["st"]
    model.initialize(0.0)
    try:
        assert model._fmu.getString([0]) == ["a name"]
        model.do_step(0.0, 0.3)
        assert list(model.get_outputs()) == [2.0, 0.0, SYMBOLS.code("even")]  # period 0.25
    finally:
        model.terminate()
    (tmp_path / "bad.toml").write_text(text.replace('"a name"', "3"))
    res = CliRunner().invoke(main, ["validate", str(tmp_path / "bad.toml")])
    assert res.exit_code == 2 and "'label' is a String, got 3" in res.output


def test_an_fmu_that_ends_the_simulation_ends_the_run_ok(fmus: dict[str, Path]) -> None:
    """FMI 2.0 terminateSimulation: the step returns fmi2Discard and fmi2GetBooleanStatus
    (fmi2Terminated) says true. The run ends ok at the last point every sub-model completed,
    naming the FMU; FMPy's simulate_fmu stops there too."""
    system = cosimstep.System()
    system.add("st", FmuSubModel(fmus["stair"], {"period": 0.5, "stop_at": 4}))
    result = cosimstep.simulate(system, 10.0, cosimstep.Fixed(0.1))
    assert result.status == "ok" and result.success
    assert "'st' ended the simulation: terminateSimulation" in result.message
    assert result.t_end == pytest.approx(1.4)  # the counter reaches 4 at t = 1.5
    assert result["st.counter"][-1] == 3.0
    theirs = fmpy.simulate_fmu(str(fmus["stair"]), stop_time=10.0, step_size=0.1,
                               output_interval=0.1, start_values={"period": 0.5, "stop_at": 4})
    assert theirs["time"][-1] < 2.0  # FMPy ends there as well (keeping the FMU's last value)


def test_array_values_are_flattened_row_major() -> None:
    """FMI 3.0 array start values and TOML arrays, as the adapter hands them to the FMU (its
    element ports ``name[1]`` … follow the same order). Measured end to end on the FMI
    Reference StateSpace (A, x0 set from TOML): outputs y[1..3] equal to FMPy's (0.0)."""
    from cosimstep.adapters.fmu_base import array_values

    assert array_values("1 0 0 0 1 0 0 0 1") == [1, 0, 0, 0, 1, 0, 0, 0, 1]
    assert array_values([[0.0, 1.0], [2.0, 3.0]]) == [0.0, 1.0, 2.0, 3.0]
    assert array_values(0.5, 3) == [0.5, 0.5, 0.5]
    with pytest.raises(ValueError, match="2 values for an array of 3"):
        array_values([1.0, 2.0], 3)


def test_strings_are_stored_and_read_back(fmus: dict[str, Path], tmp_path: Path) -> None:
    """String ports travel as codes (cosimstep.symbols); the store keeps the codes' values,
    so a stored run decodes to the same words, also through pandas."""
    from cosimstep.store import read_run

    db = tmp_path / "words.db"
    result = cosimstep.simulate(stair_into_echo(fmus), 2.0, cosimstep.Fixed(0.1), store=db)
    assert result.success, result.message
    stored = read_run(db)
    assert stored.text("ec.s_out") == result.text("ec.s_out")
    assert set(stored.text("st.word")) == {"odd", "even"}
    frame = stored.to_pandas()
    assert list(frame["st.word"].iloc[:6]) == ["odd"] * 5 + ["even"]
    assert list(result.to_pandas()["ec.s_out"]) == result.text("ec.s_out")
    with pytest.raises(ValueError, match="not a String or Binary output"):
        result.text("st.counter")
    # the exported files hold the words too, not the codes the store keeps
    import csv

    import pandas as pd
    from scipy.io import loadmat

    from cosimstep.results import write

    with write(stored, tmp_path / "w.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [r["st.word"] for r in rows] == stored.text("st.word")
    assert [float(r["st.counter"]) for r in rows] == frame["st.counter"].tolist()
    parquet = pd.read_parquet(write(stored, tmp_path / "w.parquet"))
    assert parquet["st.word"].tolist() == stored.text("st.word")
    mat = loadmat(write(stored, tmp_path / "w.mat"))
    assert [str(w[0]) for w in mat["st_word"].ravel()] == stored.text("st.word")


def test_string_codes_are_the_same_in_every_process() -> None:
    """A code is a hash of the value, so a resumed run or a sweep worker agrees on it."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", "from cosimstep.symbols import SYMBOLS; "
                          "print(repr([SYMBOLS.code('odd'), SYMBOLS.code(b'odd')]))"],
                         capture_output=True, text=True, check=True).stdout
    assert eval(out) == [SYMBOLS.code("odd"), SYMBOLS.code(b"odd")]
    assert SYMBOLS.code("odd") != SYMBOLS.code(b"odd")
    with pytest.raises(KeyError, match="not the code of a known"):
        SYMBOLS.value(12345.0)

