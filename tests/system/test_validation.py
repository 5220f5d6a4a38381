"""System checks report every problem at once."""

from __future__ import annotations

import numpy as np
import pytest

from cosimstep import ConfigurationError, Fixed, MasterOptions, Port, System, simulate
from cosimstep.extrapolation import taylor_coefficients
from helpers import Gain, Integrator


def test_all_problems_reported_together():
    s = System()
    s.add("a", Integrator(unit="rad"))
    s.add("b", Integrator(unit="m"))
    s.add("g1", Gain())
    s.add("g2", Gain())
    loose = Integrator()
    loose.inputs = (Port("u", "1", None),)  # no start value
    s.add("loose", loose)
    s.connect("a.x", "b.u")               # unit mismatch rad -> m
    s.connect("nowhere.x", "a.u")         # unknown model
    s.connect("a.nope", "a.u")            # unknown port (and a second source into a.u)
    s.connect("b.x", "a.u")               # first source of a.u, but m -> rad: unit mismatch
    s.connect("a.x", "a.u")               # two sources into one input
    s.connect("g1.y", "g2.u")             # algebraic loop g1 <-> g2: listed, not a problem
    s.connect("g2.y", "g1.u")
    text = "\n".join(str(p) for p in s.problems())
    assert "unit mismatch" in text
    assert "unknown model 'nowhere'" in text
    assert "has no output 'nope'" in text
    assert "already has a source" in text
    assert "'loose.u' is not connected and has no start value" in text
    assert "algebraic loop" not in text and s.loops() == [["g1.u", "g1.y", "g2.u", "g2.y"]]
    with pytest.raises(ConfigurationError) as info:
        s.validate()
    assert len(info.value.problems) == 6


def test_a_system_without_outputs_is_refused_with_a_reason():
    """A lone sink (an input with a start value, no output): nothing is exchanged or recorded,
    and reading its unconnected input ended every master in an IndexError."""
    sink = Integrator()
    sink.outputs = ()
    s = System().add("sink", sink)
    with pytest.raises(ConfigurationError, match="no sub-model has an output"):
        simulate(s, 1.0, Fixed(0.1), MasterOptions("gauss-seidel", 2))


def test_malformed_addresses_and_ports_declared_twice_are_reported():
    """The quick path for plain connections must not accept what the full check refuses."""
    s = System()
    twice = Integrator(unit="m")
    twice.outputs = (Port("x", "m"), Port("x", "s"))  # one name, two ports
    s.add("a", Integrator()).add("b", Integrator()).add("twice", twice)
    s.connect("a.", "b.u")
    s.connect(".x", "b.u")
    s.connect("a", "b.u")
    s.connect("twice.x", "a.u")
    text = [str(p) for p in s.problems()]
    for address in ("'a.'", "'.x'", "'a'"):
        assert sum(f"`from` {address} is not of the form model.port" in t for t in text) == 1
    assert any("model 'twice' declares output 'x' more than once" in t for t in text)
    # a well-formed plain connection between two real ports of one unit has nothing to report
    ok = System().add("a", Integrator()).add("b", Integrator()).connect("a.x", "b.u")
    assert ok.problems() == []


def test_unit_conversion_gain_and_offset():
    """rad -> deg conversion, then gain and offset, reach the receiver."""
    s = System()
    src = Integrator(unit="rad", x0=1.0)
    dst = Integrator(unit="deg")
    s.add("src", src).add("dst", dst)
    s.connect("src.x", "dst.u", gain=2.0, offset=1.0)
    simulate(s, 0.1, Fixed(0.1), MasterOptions("jacobi", 0))
    assert dst.seen[0] == pytest.approx(2.0 * np.degrees(1.0) + 1.0)


def test_direct_feedthrough_outputs_are_settled_at_communication_points():
    """A gain between two integrators: its output equals k * input at every stored point."""
    s = System()
    s.add("i1", Integrator(x0=1.0)).add("k", Gain(3.0)).add("i2", Integrator())
    s.connect("i1.x", "k.u").connect("k.y", "i2.u")
    r = simulate(s, 1.0, Fixed(0.1))
    assert np.allclose(r["k.y"], 3.0 * r["i1.x"])
    # i2 integrates a constant 3 exactly (x1 is constant: its input is unconnected with start 0)
    assert r["i2.x"][-1] == pytest.approx(3.0)


@pytest.mark.parametrize("order", [0, 1, 2])
def test_extrapolation_is_exact_for_polynomials_of_its_order(order):
    times = [0.0, 0.3, 0.7]
    poly = np.array([0.5, -1.0, 2.0])[: order + 1]
    values = np.array([[np.polynomial.polynomial.polyval(t, poly)] for t in times])
    c = taylor_coefficients(times, values, 0.7, order)
    derivs = [np.polynomial.polynomial.polyval(0.7, np.polynomial.polynomial.polyder(poly, k))
              for k in range(order + 1)]
    assert np.allclose(c[:, 0], derivs)


def test_parameter_changes_and_master_numbers_are_checked_in_the_file(tmp_path, examples):
    """Found by trying the examples as a user would: a change before the start was applied
    from it silently, two changes of one parameter at one time were both taken, `true` was
    read as extrapolation order 1, and a change of one model's own parameter was told to check
    its spelling. Each is now a problem of its own, listed together."""
    from cosimstep import load_system

    text = (examples / "algebraic_loop.toml").read_text()
    text = text.replace("extrapolation = 2", "extrapolation = true")
    text += ("\n[[parameter_changes]]\nt = -1.0\nset = { k = 50.0 }\n"
             "\n[[parameter_changes]]\nt = 5.0\nset = { k = 50.0, c = 1.0 }\n"
             "\n[[parameter_changes]]\nt = 5.0\nset = { k = 20.0, c = 1.0 }\n"
             '\n[[parameter_changes]]\nt = 6.0\nset = { "spring.k" = 20.0 }\n')
    (tmp_path / "bad.toml").write_text(text)
    with pytest.raises(ConfigurationError) as info:
        load_system(tmp_path / "bad.toml")
    text = "\n".join(str(p) for p in info.value.problems)
    assert len(info.value.problems) == 4, text
    assert "master.extrapolation: Value error, a whole number, not true/false" in text
    assert "parameter_changes[0].t: -1 is before the run starts" in text
    assert "parameter_changes[2].set.k: parameter_changes[1] sets it to 50 at the same" in text
    assert "one model's own parameters do not change during a run" in text
