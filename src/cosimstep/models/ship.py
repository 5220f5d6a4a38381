"""The ship plant (thesis 1.1): load zones, a chilled-water network and its controller.

Three electrical load zones turn their load into heat; chilled water carries it to a chiller.
The water network (``hydraulics``) is one pump A feeding a supply main with three taps, one per
zone; the main's middle section (between taps 1 and 2) has an isolation valve at each end, and
a standby pump B can feed tap 3 through a cross-connect valve. When that section is hit it
leaks; the plant controller (``isolation``) sees the flow into the section exceed the flow
out (a differential flow meter with a 50 ms lag), closes both isolation valves, opens the
cross-connect and starts pump B: zones 2 and 3 are then fed backwards from tap 3. Zone
controllers open each zone's valve as its temperature rises (PI, anti-windup).

Units: bar, kg/s, °C, kW, kJ, s. Time scales: the network about 10 ms (pipe compliance and
water inertia), valve actuators 2 s, the chiller about 40 s, the zones several minutes.

Sub-models, with their states (all outputs are states):

    hydraulics   qa, qb (pump flows), p1, pm, p2, p3, pB (node pressures), q1, q2, q3 (zone
                 branch flows), dq (the section's metered in − out flow); inputs v1..v3 (zone
                 valves), iso, xc, pump_b, intact; outputs q1..q3, dq
    zone         T (zone temperature); inputs q (its branch flow), Ts (supply temperature)
    chiller      Ts; inputs T1..T3, q1..q3 (it computes the heat each exchanger passed)
    zone_control v1..v3 (valve positions), I1..I3 (PI integrals); inputs T1..T3
    damage       (discrete events) intact: 1, then 0 from the hit (scripted or Weibull)
    isolation    (discrete events) iso, xc, pump_b; input dq; armed at ``t_arm``, trips when
                 dq reaches ``dq_alarm`` (a state event)

The monolithic reference (:func:`monolithic`) is all of it in one ODE, with the same hit time
and the trip located by the reference's own event search.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from cosimstep.adapters.ode import InternalSolver, OdeSubModel, ParameterSchedule
from cosimstep.events import DiscreteEventModel, Timetable
from cosimstep.submodel import Port

ZONES = (1, 2, 3)


def default_parameters() -> dict[str, float]:
    """One set shared by every sub-model and the reference (each uses what it needs)."""
    p = {
        # network: pump head p0 [bar] at zero flow, qmax [kg/s]; inertances [bar s^2/kg];
        # compliances [kg/bar]; conductances [kg/s/sqrt(bar)]; branch loss R [bar s^2/kg^2]
        "p0": 5.0, "qmax": 40.0, "Ip": 0.002, "Iz": 0.002, "Rp": 0.001, "Rl": 0.01,
        "C": 0.02, "Cm": 0.01, "Ks": 60.0, "Kx": 40.0, "Kleak": 20.0, "Rz": 0.03,
        "dp_reg": 0.01, "v_eps": 1e-3,
        # heat: cp [kJ/kg/K], exchanger UA [kW/K], zone heat capacity [kJ/K], ambient
        "cp": 4.186, "UA": 20.0, "Cz": 5000.0, "UAamb": 0.5, "Tamb": 30.0,
        # chiller: water mass [kg], gain [kW/K], setpoint, capacity [kW]
        "Mw": 2000.0, "Kch": 200.0, "Tch": 6.0, "Qch_max": 800.0,
        # zone control: setpoint, PI gains, bias, limits, actuator time constant, tracking time
        "Tset": 22.0, "kp": 0.1, "ki": 0.002, "v0": 0.4, "vmin": 0.05, "tau_v": 2.0,
        "Tt": 30.0,
        # plant control: armed after t_arm [s]; trips when the metered leak dq (lag tau_m [s])
        # reaches dq_alarm [kg/s]
        "t_arm": 5.0, "dq_alarm": 2.0, "tau_m": 0.05,
        # damage: the middle section is hit at t_hit [s] (inf: never), or, with hit_scale > 0,
        # after a Weibull lifetime (scale [s], shape) drawn with seed hit_seed
        "t_hit": 200.0, "hit_scale": 0.0, "hit_shape": 2.0, "hit_seed": 0.0,
    }
    for i, load in zip(ZONES, (150.0, 120.0, 180.0)):
        p[f"P{i}"] = load  # electrical load [kW], all of it ends as heat
        p[f"dP{i}"] = 0.2  # relative swing of the load
        p[f"period{i}"] = 60.0 * (2 + i)  # its period [s]
    return p


HYDRAULIC_STATES = ("qa", "qb", "p1", "pm", "p2", "p3", "pB", "q1", "q2", "q3", "dq")
# the network's steady state with every zone valve at 0.4 (scipy.optimize.fsolve on
# hydraulics_rhs), so a run does not start with a pressure transient
HYDRAULIC_START = {"qa": 13.8603539, "qb": 0.0, "p1": 4.06894515, "pm": 4.03779165,
                   "p2": 4.00663815, "p3": 3.99547597, "pB": 0.0, "q1": 4.64621624,
                   "q2": 4.61030063, "q3": 4.603837, "dq": 0.0}
THERMAL_START = {"T1": 22.0, "T2": 22.0, "T3": 22.0, "Ts": 8.3}
CONTROL_START = {"v1": 0.4, "v2": 0.4, "v3": 0.4, "I1": 0.0, "I2": 0.0, "I3": 0.0}
START = (*HYDRAULIC_STATES, *THERMAL_START, *CONTROL_START)
START_VALUES = {**HYDRAULIC_START, **THERMAL_START, **CONTROL_START}


def _flow(dp: float, k: float, reg: float) -> float:
    """Turbulent flow through a conductance, ``k·√Δp`` with a regularised origin."""
    return k * dp / math.sqrt(abs(dp) + reg)


def hydraulics_rhs(x: Sequence[float], v: Sequence[float], iso: float, xc: float, pump_b: float,
                   intact: float, p: Mapping[str, float]) -> np.ndarray:
    """The network: pump flows, node pressures, branch flows, the leak meter."""
    qa, qb, p1, pm, p2, p3, pb, q1, q2, q3, dq = x
    reg = p["dp_reg"]
    q1m = iso * _flow(p1 - pm, p["Ks"], reg)
    qm2 = iso * _flow(pm - p2, p["Ks"], reg)
    q23 = _flow(p2 - p3, p["Ks"], reg)
    qx = xc * _flow(pb - p3, p["Kx"], reg)
    leak = (1.0 - intact) * _flow(max(pm, 0.0), p["Kleak"], reg)

    def pump(q: float, on: float, discharge: float) -> float:
        head = on * p["p0"] * (1.0 - (q / p["qmax"]) ** 2)
        return (head - discharge - p["Rp"] * q * abs(q) - p["Rl"] * q) / p["Ip"]

    def branch(q: float, pressure: float, opening: float) -> float:
        loss = p["Rz"] * q * abs(q) / (opening * opening + p["v_eps"])
        return (pressure - loss - p["Rl"] * q) / p["Iz"]

    return np.array([
        pump(qa, 1.0, p1), pump(qb, pump_b, pb),
        (qa - q1m - q1) / p["C"], (q1m - qm2 - leak) / p["Cm"],
        (qm2 - q23 - q2) / p["C"], (q23 + qx - q3) / p["C"], (qb - qx) / p["C"],
        branch(q1, p1, v[0]), branch(q2, p2, v[1]), branch(q3, p3, v[2]),
        (q1m - qm2 - dq) / p["tau_m"]])


def exchanger_heat(q: float, t_zone: float, t_supply: float, p: Mapping[str, float]) -> float:
    """Heat [kW] a zone passes to its water: ε·q·cp·(T − Ts), ε = 1 − exp(−UA / (q cp))."""
    capacity = max(q, 0.0) * p["cp"]
    if capacity <= 0.0:
        return 0.0
    return (1.0 - math.exp(-p["UA"] / capacity)) * capacity * (t_zone - t_supply)


def zone_load(i: int, t: float, p: Mapping[str, float]) -> float:
    return p[f"P{i}"] * (1.0 + p[f"dP{i}"] * math.sin(2.0 * math.pi * t / p[f"period{i}"]))


def zone_rhs(i: int, t: float, temp: float, q: float, t_supply: float,
             p: Mapping[str, float]) -> float:
    heat = exchanger_heat(q, temp, t_supply, p)
    return (zone_load(i, t, p) - heat - p["UAamb"] * (temp - p["Tamb"])) / p["Cz"]


def chiller_rhs(t_supply: float, temps: Sequence[float], flows: Sequence[float],
                p: Mapping[str, float]) -> float:
    picked = sum(exchanger_heat(q, tz, t_supply, p) for q, tz in zip(flows, temps))
    removed = min(max(p["Kch"] * (t_supply - p["Tch"]), 0.0), p["Qch_max"])
    return (picked - removed) / (p["Mw"] * p["cp"])


def control_rhs(valves: Sequence[float], integrals: Sequence[float], temps: Sequence[float],
                p: Mapping[str, float]) -> np.ndarray:
    """PI per zone on T − Tset, back-calculation anti-windup, first-order valve actuators."""
    dv, di = [], []
    for v, integral, temp in zip(valves, integrals, temps):
        e = temp - p["Tset"]
        command = p["v0"] + p["kp"] * e + p["ki"] * integral
        held = min(max(command, p["vmin"]), 1.0)
        dv.append((held - v) / p["tau_v"])
        di.append(e + (held - command) / (p["ki"] * p["Tt"]))
    return np.array(dv + di)


def _ports(names: Sequence[str], start: Mapping[str, float], defaults: Mapping[str, float],
           unit: Mapping[str, str]) -> list[Port]:
    return [Port(n, unit.get(n, unit.get(n[0], "1")), float(start.get(n, defaults[n])))
            for n in names]


UNITS = {"q": "kg/s", "p": "bar", "T": "degC", "v": "1", "I": "K s", "dq": "kg/s"}
"""Units by state name, or by its first letter."""


def hydraulics(parameters: ParameterSchedule, start: Mapping[str, float],
               solver: InternalSolver | None = None) -> OdeSubModel:
    """The water network (stiff: give it an implicit internal solver)."""

    def rhs(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
        return hydraulics_rhs(x, u[:3], u[3], u[4], u[5], u[6], p)

    inputs = [Port(f"v{i}", "1", float(start.get(f"v{i}", CONTROL_START[f"v{i}"])))
              for i in ZONES]
    inputs += [Port("iso", "1", 1.0), Port("xc", "1", 0.0), Port("pump_b", "1", 0.0),
               Port("intact", "1", 1.0)]
    states = _ports(HYDRAULIC_STATES, start, HYDRAULIC_START, UNITS)
    return OdeSubModel(rhs, states, inputs=inputs, outputs=["q1", "q2", "q3", "dq"],
                       parameters=parameters, solver=solver)


def zone(i: int, parameters: ParameterSchedule, start: Mapping[str, float],
         solver: InternalSolver | None = None) -> OdeSubModel:
    """Zone ``i``'s temperature ``T``; inputs its branch flow ``q`` and the supply ``Ts``."""

    def rhs(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
        return np.array([zone_rhs(i, t, x[0], u[0], u[1], p)])

    name = f"T{i}"
    states = [Port("T", "degC", float(start.get(name, THERMAL_START[name])))]
    inputs = [Port("q", "kg/s", float(start.get(f"q{i}", HYDRAULIC_START[f"q{i}"]))),
              Port("Ts", "degC", float(start.get("Ts", THERMAL_START["Ts"])))]
    return OdeSubModel(rhs, states, inputs=inputs, parameters=parameters, solver=solver)


def chiller(parameters: ParameterSchedule, start: Mapping[str, float],
            solver: InternalSolver | None = None) -> OdeSubModel:
    """Supply temperature ``Ts``; inputs the zone temperatures and branch flows."""

    def rhs(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
        return np.array([chiller_rhs(x[0], u[:3], u[3:], p)])

    inputs = _ports([f"T{i}" for i in ZONES], start, THERMAL_START, UNITS)
    inputs += _ports([f"q{i}" for i in ZONES], start, HYDRAULIC_START, UNITS)
    return OdeSubModel(rhs, _ports(["Ts"], start, THERMAL_START, UNITS), inputs=inputs,
                       parameters=parameters, solver=solver)


def zone_control(parameters: ParameterSchedule, start: Mapping[str, float],
                 solver: InternalSolver | None = None) -> OdeSubModel:
    """The zone level of the controller: valve positions ``v1..v3`` from the temperatures."""

    def rhs(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
        return control_rhs(x[:3], x[3:], u, p)

    states = _ports(list(CONTROL_START), start, CONTROL_START, UNITS)
    inputs = _ports([f"T{i}" for i in ZONES], start, THERMAL_START, UNITS)
    return OdeSubModel(rhs, states, inputs=inputs, outputs=["v1", "v2", "v3"],
                       parameters=parameters, solver=solver)


class Isolation(DiscreteEventModel):
    """The plant level of the controller: isolates the damaged section.

    Armed at ``t_arm`` (a scheduled event: the start-up transient must not trip it); then its
    indicator ``dq − dq_alarm`` rises through zero when the metered leak reaches ``dq_alarm``
    (a state event): it closes the isolation valves (``iso`` 0), opens the
    cross-connect (``xc`` 1) and starts pump B (``pump_b`` 1). It trips once.
    """

    kind = "ship.isolation"

    def __init__(self, t_arm: float, dq_alarm: float) -> None:
        self.t_arm, self.dq_alarm = float(t_arm), float(dq_alarm)
        self.inputs = (Port("dq", "kg/s", 0.0, "the guarded section's flow in minus out"),)
        self.outputs = (Port("iso", "1", 1.0, "isolation valves: 1 open"),
                        Port("xc", "1", 0.0, "cross-connect valve: 1 open"),
                        Port("pump_b", "1", 0.0, "standby pump: 1 running"))
        super().__init__()
        self._armed = False

    def initialize(self, t0: float) -> None:
        super().initialize(t0)
        self._armed = t0 >= self.t_arm

    def next_event(self, t: float) -> float:
        return self.t_arm if not self._armed and t < self.t_arm else math.inf

    def indicator(self, inputs: np.ndarray) -> float | None:
        if not self._armed or self._y[0] < 0.5:
            return -1.0  # not armed yet, or tripped already: nothing can cross
        return float(inputs[0]) - self.dq_alarm

    def fire(self, t: float, inputs: np.ndarray) -> tuple[np.ndarray, str]:
        if not self._armed:
            self._armed = True
            return self._y.copy(), "armed"
        return np.array([0.0, 1.0, 1.0]), "isolate"

    def _state(self) -> bool:
        return self._armed

    def _set_state(self, state: bool) -> None:
        self._armed = state


def hit_time(p: Mapping[str, float]) -> float:
    """When the middle section is hit: ``t_hit``, or a Weibull lifetime when ``hit_scale`` > 0
    (the same draw as a ``failure`` model with that law, scale, shape and seed)."""
    if p["hit_scale"] <= 0.0:
        return float(p["t_hit"])
    from cosimstep.events import FailureModel

    model = FailureModel("weibull", scale=p["hit_scale"], shape=p["hit_shape"],
                         seed=int(p["hit_seed"]))
    model.initialize(0.0)
    return model.next_event(0.0)


def damage(parameters: ParameterSchedule, start: Mapping[str, float],
           solver: InternalSolver | None = None) -> Timetable:
    """The damage model: ``intact`` 1, then 0 from :func:`hit_time` on."""
    t = hit_time(parameters.at(0.0))
    times, values = ([t], [[0.0]]) if math.isfinite(t) else ([], [])
    return Timetable(times, values, outputs=["intact"], start=[1.0])


def isolation(parameters: ParameterSchedule, start: Mapping[str, float],
              solver: InternalSolver | None = None) -> Isolation:
    p = parameters.at(0.0)
    return Isolation(p["t_arm"], p["dq_alarm"])


class ShipMonolithic(OdeSubModel):
    """The whole plant as one ODE; the hit is a time event, the trip a state event that the
    reference locates (:meth:`state_events`, :meth:`on_state_event`)."""

    reference_method = "Radau"
    """The network is stiff (eigenvalues to about −1e3/s over a 600 s run): DOP853 at the
    reference's tolerance would take millions of steps held to its stability bound."""

    def __init__(self, parameters: ParameterSchedule, start: Mapping[str, float],
                 solver: InternalSolver | None = None) -> None:
        p0 = parameters.at(0.0)
        self.t_hit, self.t_arm, self.dq_alarm = hit_time(p0), p0["t_arm"], p0["dq_alarm"]
        self.tripped = False
        defaults = {**HYDRAULIC_START, **THERMAL_START, **CONTROL_START}
        names = [*HYDRAULIC_STATES, "T1", "T2", "T3", "Ts", *CONTROL_START]
        events = [self.t_hit] if math.isfinite(self.t_hit) else []
        super().__init__(self._rhs, _ports(names, start, defaults, UNITS),
                         parameters=parameters, solver=solver, time_events=events)

    def initialize(self, t0: float) -> None:
        super().initialize(t0)
        self.tripped = False

    def _rhs(self, t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
        n = len(HYDRAULIC_STATES)
        hyd, temps, ts = x[:n], x[n:n + 3], x[n + 3]
        valves, integrals = x[n + 4:n + 7], x[n + 7:n + 10]
        iso, on = (0.0, 1.0) if self.tripped else (1.0, 0.0)
        intact = 0.0 if t >= self.t_hit else 1.0
        flows = hyd[7:10]
        return np.concatenate([
            hydraulics_rhs(hyd, valves, iso, on, on, intact, p),
            [zone_rhs(i, t, temps[i - 1], flows[i - 1], ts, p) for i in ZONES],
            [chiller_rhs(ts, temps, flows, p)],
            control_rhs(valves, integrals, temps, p)])

    def state_events(self) -> list:
        """Indicators ``g(t, x)`` whose rise through zero is an event (``[]``: none left)."""
        if self.tripped:
            return []
        dq = HYDRAULIC_STATES.index("dq")
        return [lambda t, x: (x[dq] - self.dq_alarm) if t >= self.t_arm else -1.0]

    def on_state_event(self, index: int, t: float, x: np.ndarray) -> None:
        self.tripped = True


def monolithic(parameters: ParameterSchedule, start: Mapping[str, float],
               solver: InternalSolver | None = None) -> ShipMonolithic:
    return ShipMonolithic(parameters, start, solver)
