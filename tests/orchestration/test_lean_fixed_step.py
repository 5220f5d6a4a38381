"""The lean fixed-step loop (``Fixed`` controller) and the general controller loop give the same
run: values, times, calls, step sizes, stored rows, failures — on the split double pendulum with
time events (toggled), and on a chain with a gain, an offset, a unit change, direct feedthrough
and an unconnected input."""

from __future__ import annotations

import gc
import sqlite3
import threading
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from cosimstep import Fixed, MasterOptions, System, load_system, read_run, simulate
from cosimstep.submodel import Capabilities, Port, SubModel
from helpers import Clock, Gain, Integrator


class GeneralFixed(Fixed):
    """The same controller, but not ``Fixed`` itself: ``simulate`` takes the general loop."""


def assert_same_run(lean, general, bound: float | None = None) -> None:
    """The two loops' runs are the same; values bit for bit, or within ``bound`` (relative to
    each column's largest value, at least 1) when one is given."""
    assert lean.status == general.status and lean.message == general.message
    assert lean.t_end == general.t_end
    assert np.array_equal(lean.times, general.times)
    if bound is None:
        assert np.array_equal(lean.values, general.values)  # bit for bit
    else:
        assert within(lean.values, general.values, bound)
    assert np.array_equal(lean.step_sizes, general.step_sizes)
    assert lean.calls == general.calls
    assert (lean.steps_accepted, lean.steps_rejected) == \
        (general.steps_accepted, general.steps_rejected)
    assert {n: (m.calls, m.accepted, m.rejected) for n, m in lean.models.items()} == \
        {n: (m.calls, m.accepted, m.rejected) for n, m in general.models.items()}
    if general.error is not None:
        if bound is None:
            assert lean.error.max_abs == general.error.max_abs
        else:
            assert abs(lean.error.max_abs - general.error.max_abs) <= bound


def assert_same_store(a: Path, b: Path) -> None:
    ra, rb = read_run(a), read_run(b)
    assert (ra.status, ra.message) == (rb.status, rb.message)
    assert np.array_equal(ra.times, rb.times) and np.array_equal(ra.values, rb.values)
    assert np.array_equal(ra.attempts, rb.attempts)
    assert ra.attempt_models == rb.attempt_models
    assert ra.summary["calls"] == rb.summary["calls"]
    assert (ra.reference is None) == (rb.reference is None)
    if ra.reference is not None:
        assert np.array_equal(ra.reference, rb.reference)


@pytest.mark.parametrize("master", ["jacobi", "gauss-seidel"])
@pytest.mark.parametrize("order", [0])
def test_toggled_pendulum_same_run_both_loops(examples: Path, tmp_path: Path, master: str,
                                              order: int) -> None:
    """Time events at 1 s and 2 s: landing, extrapolation restart, grey-box slopes. (Orders 1
    and 2: the extrapolating kernel, test_extrapolating_kernel_agrees_with_the_general_loop.)"""
    spec = load_system(examples / "double_pendulum_toggled.toml")
    runs = {}
    for label, controller in (("lean", Fixed(0.01)), ("general", GeneralFixed(0.01))):
        runs[label] = simulate(spec.system, 2.5, controller, MasterOptions(master, order),
                               reference=spec.reference, store=tmp_path / f"{label}.db")
    assert runs["lean"].success and runs["lean"].steps_accepted == 250
    assert 1.0 in runs["lean"].times and 2.0 in runs["lean"].times
    assert_same_run(runs["lean"], runs["general"])
    assert_same_store(tmp_path / "lean.db", tmp_path / "general.db")


def chain() -> System:
    """clock → (gain 2, offset 1, s → ms) → a → (ms → s) → b; d → feedthrough gain → c → (gain
    −0.5) → d; one more integrator has no connection (its input's start value)."""
    s = System()
    s.add("clock", Clock()).add("a", Integrator(unit="ms")).add("b", Integrator(unit="s"))
    s.add("g", Gain(3.0)).add("c", Integrator()).add("d", Integrator(x0=1.0))
    s.add("idle", Integrator())
    s.connect("clock.time", "a.u", gain=2.0, offset=1.0).connect("a.x", "b.u")
    s.connect("d.x", "g.u").connect("g.y", "c.u").connect("c.x", "d.u", gain=-0.5)
    return s


@pytest.mark.parametrize("master", ["jacobi", "gauss-seidel"])
@pytest.mark.parametrize("order", [0, 2])
def test_chain_with_conversions_and_feedthrough(master: str, order: int) -> None:
    lean = simulate(chain(), 1.0, Fixed(0.1), MasterOptions(master, order))
    general = simulate(chain(), 1.0, GeneralFixed(0.1), MasterOptions(master, order))
    assert lean.success and lean.values[-1, 2] != 0.0
    assert_same_run(lean, general)


def held_chain() -> System:
    """No feedthrough, sources out of column order and a gain: the held kernel's gather path."""
    s = System()
    s.add("a", Integrator(x0=1.0)).add("b", Integrator(x0=2.0)).add("c", Integrator())
    s.connect("b.x", "a.u", gain=-1.0).connect("c.x", "b.u").connect("a.x", "c.u")
    return s


@pytest.mark.parametrize("master", ["jacobi", "gauss-seidel"])
def test_held_kernel_on_python_models(master: str) -> None:
    lean = simulate(held_chain(), 2.0, Fixed(0.05), MasterOptions(master, 0))
    general = simulate(held_chain(), 2.0, GeneralFixed(0.05), MasterOptions(master, 0))
    assert lean.success
    assert_same_run(lean, general)


def failing(mode: str) -> System:
    s = System()
    s.add("clock", Clock(fail_at=0.5, mode=mode)).add("sink", Integrator(unit="s"))
    s.connect("clock.time", "sink.u")
    return s


@pytest.mark.parametrize("mode", ["raise", "nan", "hang"])
@pytest.mark.parametrize("order", [0])
def test_failures_end_both_loops_alike(tmp_path: Path, mode: str, order: int) -> None:
    runs = {}
    for label, controller in (("lean", Fixed(0.1)), ("general", GeneralFixed(0.1))):
        options = MasterOptions("jacobi", order, call_timeout=0.3 if mode == "hang" else None)
        runs[label] = simulate(failing(mode), 1.0, controller, options,
                               store=tmp_path / f"{label}.db")
    assert runs["lean"].status == "failed" and runs["lean"].steps_accepted == 5
    assert "'clock'" in runs["lean"].message and "t = 0.5" in runs["lean"].message
    assert_same_run(runs["lean"], runs["general"])
    assert_same_store(tmp_path / "lean.db", tmp_path / "general.db")


def test_timeout_watch_lets_normal_runs_finish() -> None:
    """With call_timeout the lean loop runs in a watched worker thread; a run whose calls are all
    quick is unchanged by it."""
    spec = load_system(Path(__file__).parents[2] / "examples" / "double_pendulum_slow.toml")
    watched = simulate(spec.system, 0.5, Fixed(0.01), MasterOptions("jacobi", 0,
                                                                     call_timeout=5.0))
    plain = simulate(spec.system, 0.5, Fixed(0.01), MasterOptions("jacobi", 0))
    assert watched.success
    assert_same_run(watched, plain)


def test_held_kernel_applies_exactly_without_extrapolation_and_feedthrough() -> None:
    from cosimstep.masters import Master

    for master in ("jacobi", "gauss-seidel"):
        assert Master(held_chain().compile(), MasterOptions(master, 0)).held_kernel() is not None
        assert Master(held_chain().compile(), MasterOptions(master, 1)).held_kernel() is None
        assert Master(chain().compile(), MasterOptions(master, 0)).held_kernel() is None
        for order in (1, 2):  # held_chain's integrators take input derivatives
            assert Master(held_chain().compile(),
                          MasterOptions(master, order)).extrapolating_kernel() is not None
            assert Master(mixed_chain().compile(),
                          MasterOptions(master, order)).extrapolating_kernel() is not None
            assert Master(chain().compile(),
                          MasterOptions(master, order)).extrapolating_kernel() is None
        assert Master(mixed_chain().compile(), MasterOptions(master, 0)).extrapolating_kernel() \
            is None


class Released(SubModel):
    """Steps at once, except the step from ``slow_at``: it waits until ``release`` is set."""

    def __init__(self, slow_at: float, release: threading.Event) -> None:
        self.inputs = ()
        self.outputs = (Port("time", "s", 0.0),)
        self.slow_at, self.release = slow_at, release
        self.t, self.steps = 0.0, 0

    def set_inputs(self, values: np.ndarray) -> None:
        pass

    def do_step(self, t: float, h: float) -> None:
        if abs(t - self.slow_at) < 1e-9:
            self.release.wait(10.0)
        self.steps += 1
        self.t = t + h

    def get_outputs(self) -> np.ndarray:
        return np.array([self.t])


def test_call_ending_while_the_watchdog_gives_up_stops_the_run(monkeypatch) -> None:
    """The call from t = 0.5 runs past the timeout and returns just while the watchdog decides
    to abandon it (forced here: the watchdog's "still the same call?" lets the call return and
    waits). The run must end there as timed out — the worker must not go on stepping (and
    writing rows) after the run has been given up."""
    import cosimstep.masters as masters

    release = threading.Event()
    give_up = masters._Watchdog._give_up

    def late_give_up(self: masters._Watchdog, token: int) -> bool:
        """Raise the flag, then let the blocked call return and reach its end before the
        watchdog looks whether it is still the same call."""
        self.abandoned = True
        release.set()
        time.sleep(0.3)
        return give_up(self, token)

    monkeypatch.setattr(masters._Watchdog, "_give_up", late_give_up)
    model = Released(0.5, release)
    s = System()
    s.add("clock", model).add("sink", Integrator(unit="s"))
    s.connect("clock.time", "sink.u")
    result = simulate(s, 100.0, Fixed(0.1), MasterOptions("jacobi", 0, call_timeout=0.2))
    steps_at_return = model.steps
    time.sleep(0.3)
    assert result.status == "failed" and "no answer within 0.2 s" in result.message
    assert result.steps_accepted == 5 and result.t_end == 0.5
    assert model.steps == steps_at_return <= 6  # nothing stepped after the run ended


class Probe(SubModel):
    """Takes 10 ms a step; at ``probe_at`` counts the points already committed to ``db``."""

    def __init__(self, db: Path, probe_at: float) -> None:
        self.inputs = ()
        self.outputs = (Port("time", "s", 0.0),)
        self.db, self.probe_at = db, probe_at
        self.t, self.committed = 0.0, None

    def set_inputs(self, values: np.ndarray) -> None:
        pass

    def do_step(self, t: float, h: float) -> None:
        time.sleep(0.01)
        if abs(t - self.probe_at) < 1e-9:
            with sqlite3.connect(self.db) as db:
                self.committed = db.execute("SELECT COALESCE(SUM(n), 0) FROM point_block"
                                            ).fetchone()[0]
        self.t = t + h

    def get_outputs(self) -> np.ndarray:
        return np.array([self.t])


@pytest.mark.parametrize("controller", [Fixed, GeneralFixed])
def test_slow_steps_reach_the_store_while_the_run_goes_on(tmp_path: Path, controller) -> None:
    """The store commits every 0.5 s what it was given; the lean loop hands it rows in batches,
    which must be small enough with slow steps (was: 256 steps, here 2.6 s, so a crash after
    1 s kept nothing)."""
    db = tmp_path / "slow.db"
    probe = Probe(db, 1.0)
    s = System()
    s.add("probe", probe).add("sink", Integrator(unit="s"))
    s.connect("probe.time", "sink.u")
    result = simulate(s, 1.2, controller(0.01), MasterOptions("jacobi", 0), store=db)
    assert result.success
    assert probe.committed is not None and probe.committed >= 20  # ~0.5 s of steps or more


@pytest.mark.parametrize("controller", [Fixed, GeneralFixed])
def test_runs_with_call_timeout_leave_no_threads_behind(controller) -> None:
    """Each run with call_timeout used to leave its call worker waiting forever (the lean loop
    started one and never used it)."""
    before = set(threading.enumerate())
    for _ in range(3):
        options = MasterOptions("jacobi", 0, call_timeout=5.0)
        assert simulate(held_chain(), 0.5, controller(0.05), options).success
    gc.collect()
    deadline = time.monotonic() + 5.0
    while set(threading.enumerate()) - before and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not set(threading.enumerate()) - before


def test_sub_models_are_terminated_when_the_last_rows_cannot_be_stored(
        tmp_path: Path, monkeypatch) -> None:
    """The lean loop hands its last rows to the store after the loop; if that fails, the
    sub-models (FMU instances, unpacked folders) must still be terminated."""
    from cosimstep.store import Store

    terminated = []

    class Tracked(Integrator):
        def terminate(self) -> None:
            terminated.append(True)

    def full(*args, **kwargs) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(Store, "add_points", full)
    s = System()
    s.add("a", Tracked())
    with pytest.raises(OSError, match="disk full"):
        simulate(s, 0.5, Fixed(0.1), MasterOptions("jacobi", 0), store=tmp_path / "r.db")
    assert terminated


# -- extrapolation orders 1 and 2: the extrapolating kernel ----------------------------------------
# Sub-models without input derivatives get the input polynomial's mid-step value, those with
# input derivatives its value and derivatives at the step's start; on uniform steps the lean
# loop takes them as fixed weights of stored rows, the general loop from Taylor coefficients:
# the same run up to rounding. Measured: the toggled pendulum to 2.5 s (time events at 1 s and
# 2 s) differs by at most 2.0e-15 without input derivatives and 2.9e-15 with them (values of
# order 1); the chains below by at most 3.2e-16 (3.8e-16 with input derivatives) of the
# column's largest value. The bound asserted, relative to each column's largest value (at
# least 1):
AGREE = 1e-13


def within(a: np.ndarray, b: np.ndarray, bound: float) -> bool:
    scale = np.maximum(np.max(np.abs(b), axis=0, initial=0.0), 1.0)
    return a.shape == b.shape and bool(np.all(np.abs(a - b) <= bound * scale))


def without_input_derivatives(system: System) -> System:
    for model in system.models.values():
        model.capabilities = replace(model.capabilities, max_input_derivative_order=0)
    return system


def assert_agreeing_run(lean, general, bound: float = AGREE) -> None:
    """Everything as :func:`assert_same_run` but the values, which agree to ``bound``."""
    assert_same_run(lean, general, bound)


def assert_agreeing_store(a: Path, b: Path, bound: float = AGREE) -> None:
    ra, rb = read_run(a), read_run(b)
    assert (ra.status, ra.message) == (rb.status, rb.message)
    assert np.array_equal(ra.times, rb.times)
    assert within(ra.values, rb.values, bound)
    assert np.array_equal(ra.attempts, rb.attempts)
    assert ra.attempt_models == rb.attempt_models
    assert ra.summary["calls"] == rb.summary["calls"]


class KernelSteps:
    """Counts the steps the general :meth:`Master.step` and the extrapolating kernel make."""

    def __init__(self, monkeypatch) -> None:
        from cosimstep import masters

        self.general = self.lean = 0
        general, lean = masters.Master.step, masters._ExtrapolatingKernel.step

        def count_general(master, *args, **kwargs):
            self.general += 1
            return general(master, *args, **kwargs)

        def count_lean(kernel, *args, **kwargs):
            self.lean += 1
            return lean(kernel, *args, **kwargs)

        monkeypatch.setattr(masters.Master, "step", count_general)
        monkeypatch.setattr(masters._ExtrapolatingKernel, "step", count_lean)


@pytest.mark.parametrize("master", ["jacobi", "gauss-seidel"])
@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("derivatives", [False, True], ids=["held", "derivatives"])
def test_extrapolating_kernel_agrees_with_the_general_loop(examples: Path, tmp_path: Path,
                                                           master: str, order: int,
                                                           derivatives: bool,
                                                           monkeypatch) -> None:
    """The toggled pendulum, with bars that hold their inputs over a step or (as defined) take
    input derivatives: time events at 1 s and 2 s restart the extrapolation (the general step
    does the first `order` steps of each segment, with grey-box slopes at the first, and the
    steps landing on an event)."""
    spec = load_system(examples / "double_pendulum_toggled.toml")
    system = spec.system if derivatives else without_input_derivatives(spec.system)
    count = KernelSteps(monkeypatch)
    lean = simulate(system, 2.5, Fixed(0.01), MasterOptions(master, order),
                    reference=spec.reference, store=tmp_path / "lean.db")
    steps = (count.general, count.lean)
    general = simulate(system, 2.5, GeneralFixed(0.01), MasterOptions(master, order),
                       reference=spec.reference, store=tmp_path / "general.db")
    assert lean.success and lean.steps_accepted == 250
    assert lean.calls == {"bar1": 250, "bar2": 250}
    assert 1.0 in lean.times and 2.0 in lean.times
    assert steps[0] <= 3 * (order + 1) and steps[0] + steps[1] == 250  # 3 segments
    assert not np.array_equal(lean.values, general.values)  # the kernel ran: not bit-identical
    assert_agreeing_run(lean, general)
    assert_agreeing_store(tmp_path / "lean.db", tmp_path / "general.db")


class HeldIntegrator(Integrator):
    """An integrator that holds its input over a step (no input derivatives)."""

    def __init__(self, unit: str = "1", x0: float = 0.0) -> None:
        super().__init__(unit, x0)
        self.capabilities = replace(self.capabilities, max_input_derivative_order=0)


class Mixer(SubModel):
    """x' = u1 - 2 u2 + x/4 (inputs held over a step)."""

    def __init__(self) -> None:
        self.inputs = (Port("u1", "s", 0.0), Port("u2", "s", 0.0))
        self.outputs = (Port("x", "s", 0.5),)
        self.x, self.u = 0.5, np.zeros(2)

    def initialize(self, t0: float) -> None:
        self.x = 0.5

    def set_inputs(self, values: np.ndarray) -> None:
        self.u = np.array(values, float)

    def do_step(self, t: float, h: float) -> None:
        self.x += h * (self.u[0] - 2.0 * self.u[1] + self.x / 4)

    def get_outputs(self) -> np.ndarray:
        return np.array([self.x])


class DerivativeMixer(Mixer):
    """The mixer following its inputs' first two derivatives over a step (Taylor terms)."""

    def __init__(self) -> None:
        super().__init__()
        self.capabilities = Capabilities(max_input_derivative_order=2)
        self.du = np.zeros((2, 2))

    def set_inputs(self, values: np.ndarray) -> None:
        super().set_inputs(values)
        self.du = np.zeros((2, 2))

    def set_input_derivatives(self, derivatives: np.ndarray) -> None:
        self.du = np.zeros((2, 2))
        self.du[:derivatives.shape[0]] = derivatives

    def do_step(self, t: float, h: float) -> None:
        mix = np.array([1.0, -2.0])
        self.x += h * (mix @ self.u + self.x / 4) + h * h / 2 * (mix @ self.du[0]) \
            + h**3 / 6 * (mix @ self.du[1])


def mixed_chain(derivatives: bool = False) -> System:
    """a ← (−b, s → ms); b ← c; c ← (a in ms → s, d) through a mixer of a source stepped before
    it and one stepped after it (Gauss–Seidel: one fresh, one extrapolated); d ← c; an
    unconnected input. Sources out of column order, a gain, unit changes: gathered inputs.
    ``derivatives``: every model but ``idle`` takes input derivatives (order 2)."""
    integrator = Integrator if derivatives else HeldIntegrator
    s = System()
    s.add("a", integrator(unit="ms", x0=1.0)).add("b", integrator(unit="s", x0=2.0))
    s.add("c", DerivativeMixer() if derivatives else Mixer())
    s.add("d", integrator(unit="s")).add("idle", HeldIntegrator())
    s.connect("b.x", "a.u", gain=-1.0).connect("c.x", "b.u")
    s.connect("a.x", "c.u1").connect("d.x", "c.u2").connect("c.x", "d.u")
    return s


@pytest.mark.parametrize("master, sequence", [("jacobi", None), ("gauss-seidel", None),
                                              ("gauss-seidel", ("d", "c", "idle", "b", "a"))])
@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("derivatives", [False, True], ids=["held", "derivatives"])
def test_extrapolating_kernel_on_gathered_inputs(master: str, sequence: tuple | None, order: int,
                                                 derivatives: bool, monkeypatch) -> None:
    count = KernelSteps(monkeypatch)
    options = MasterOptions(master, order, order=sequence)
    lean = simulate(mixed_chain(derivatives), 2.0, Fixed(0.05), options)
    # the general step: the first `order` steps, and the last if its h = until - t is not
    # exactly 0.05
    assert order <= count.general <= order + 1 and count.general + count.lean == 40
    general = simulate(mixed_chain(derivatives), 2.0, GeneralFixed(0.05), options)
    assert lean.success and np.all(lean.values[-1, :4] != 0.0)
    assert not np.array_equal(lean.values, general.values)
    assert_agreeing_run(lean, general)


def failing_held(mode: str, derivatives: bool = False) -> System:
    s = System()
    sink = Integrator(unit="s") if derivatives else HeldIntegrator(unit="s")
    s.add("clock", Clock(fail_at=0.5, mode=mode)).add("sink", sink)
    s.connect("clock.time", "sink.u")
    return s


@pytest.mark.parametrize("mode", ["raise", "nan", "hang"])
@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("derivatives", [False, True], ids=["held", "derivatives"])
def test_failures_in_the_extrapolating_kernel_end_both_loops_alike(
        tmp_path: Path, mode: str, order: int, derivatives: bool) -> None:
    """The failing step (from t = 0.5, the 6th) runs in the kernel: the run ends there with
    the points so far, in the result and in the store."""
    runs = {}
    for label, controller in (("lean", Fixed(0.1)), ("general", GeneralFixed(0.1))):
        options = MasterOptions("gauss-seidel", order,
                                call_timeout=0.3 if mode == "hang" else None)
        runs[label] = simulate(failing_held(mode, derivatives), 1.0, controller, options,
                               store=tmp_path / f"{label}.db")
    lean = runs["lean"]
    assert lean.status == "failed" and lean.steps_accepted == 5 and lean.t_end == 0.5
    assert "'clock'" in lean.message and "t = 0.5" in lean.message
    assert lean.calls == {"clock": 6, "sink": 6 if mode == "nan" else 5}
    assert_agreeing_run(lean, runs["general"])
    assert_agreeing_store(tmp_path / "lean.db", tmp_path / "general.db")


class Metered(SubModel):
    """Each step takes exactly one second of the clock ``now`` (a list holding its reading)."""

    def __init__(self, now: list[float]) -> None:
        self.inputs, self.outputs, self.now = (), (Port("y", "1", 0.0),), now

    def set_inputs(self, values: np.ndarray) -> None:
        pass

    def do_step(self, t: float, h: float) -> None:
        self.now[0] += 1.0

    def get_outputs(self) -> np.ndarray:
        return np.array([self.now[0]])


def test_the_held_kernel_times_a_sample_of_its_calls_and_scales_it_up(monkeypatch) -> None:
    """The lean held kernel reads the clock around one call in TIMED_EVERY, not around each;
    the time it reports is the sample's, scaled by calls over calls timed. On a clock that
    only the sub-model advances (one second a step), that is the time spent, exactly."""
    import cosimstep.masters as masters

    now = [0.0]
    reads = [0]

    def clock() -> float:
        reads[0] += 1
        return now[0]

    monkeypatch.setattr(masters, "time", SimpleNamespace(perf_counter=clock))
    s = System().add("a", Metered(now)).add("b", Metered(now))
    result = simulate(s, 2.0, Fixed(0.1), MasterOptions("jacobi", 0, call_timeout=0))
    assert result.calls == {"a": 20, "b": 20}
    assert result.time_in_models == {"a": 20.0, "b": 20.0}
    # two reads per timed call: 80 to time every call; measured 28 (80 with TIMED_EVERY = 1)
    assert reads[0] < 40


class Typed(SubModel):
    """One output returned in a given NumPy type: its value at step 5 is ``late``, t before."""

    def __init__(self, dtype: type, late: object) -> None:
        self.inputs, self.outputs = (), (Port("y", "1", 0.0),)
        self.dtype, self.late, self.t, self.steps = dtype, late, 0.0, 0

    def set_inputs(self, values: np.ndarray) -> None:
        pass

    def do_step(self, t: float, h: float) -> None:
        self.t, self.steps = t + h, self.steps + 1

    def get_outputs(self) -> np.ndarray:
        value = self.late if self.steps >= 5 else round(10 * self.t)
        return np.array([value], dtype=self.dtype)


@pytest.mark.parametrize("dtype, late", [(np.int64, 7), (np.longdouble, "1e400")],
                         ids=["int", "long double beyond float64"])
def test_outputs_that_are_no_float_are_stored_and_checked_as_by_the_general_step(
        dtype: type, late: object) -> None:
    """The held kernel stores a single float output as an item and checks the row by the
    floats' running sum; an output of another type goes the general step's way: an int is
    stored as its float, a long double beyond float64's range becomes inf and ends the run."""
    runs = []
    for controller in (Fixed(0.1), GeneralFixed(0.1)):
        s = System().add("typed", Typed(dtype, dtype(late))).add("sink", Integrator(unit="1"))
        s.connect("typed.y", "sink.u")
        runs.append(simulate(s, 1.0, controller, MasterOptions("jacobi", 0, call_timeout=0)))
    assert_same_run(*runs)
    if dtype is np.longdouble:
        assert runs[0].status == "failed" and "non-finite" in runs[0].message
    else:
        assert runs[0].success and runs[0].values[-1, 0] == 7.0
