"""The error memory of a multi-rate run: the synchronous probe of
:mod:`cosimstep.controllers.memory`, made where the sub-models stand at different times.

The multi-rate step control shares the tolerance over the run's length, as the synchronous
controllers did before they measured how long an error persists. Where the coupled system
forgets (a plant settling after a failure, a damped or stiff partition) every step then spends
a share far below what the run could afford, and the delivered error is about ``M/T`` of what
was asked (the pump-failure example: 0.02–0.1 × tol). The remedy is the same as ``pc``'s: measure
the memory ``M`` with a black-box probe and share the tolerance over ``M``.

A probe needs every sub-model at one time. In the race they are not: each stands at its own
newest point. So the probe first brings them to the time ``t*`` of the one farthest behind —
every other sub-model is restored to its latest saved state at or before ``t*`` and stepped to
``t*`` on its partners' stored trajectories (one call each) — then runs the coupled system on
synchronously, Jacobi with inputs extrapolated from its own points (the run's degree), twice:
from the state after a first step with extrapolated inputs (predictor) and from the one after
the same step with inputs interpolated through the predictor's end values (corrector), as
``pc``'s probe starts. The two differ by about a coupling error, in the direction coupling
errors take; the decay of their scaled difference is the memory (read as in
:func:`cosimstep.controllers.memory._longest`: each output's own, decay only where it has the
shape of decay, the longest counts).
Afterwards every sub-model is restored to the state it had before the probe, so the race goes
on exactly where it was: the probe changes the steps only through the memory it measures.

The probe's step is the longest step any sub-model is about to take: the memory of interest is
that of the errors the slow steps make, and a longer probe sees further for the same calls. A
probe whose steps would be unstable for the fast partition shows growth, which reads as no
decay — the safe side.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from cosimstep.controllers.memory import ErrorMemory
from cosimstep.errors import EndOfSimulation, SubModelError
from cosimstep.extrapolation import evaluate_small, taylor_coefficients

if TYPE_CHECKING:  # pragma: no cover
    from cosimstep.multirate import Multirate, Track

PROBE_EVERY = 20
"""Accepted rounds (one accepted step per continuous sub-model, on average) between probes once
the memory is known; until then, :attr:`ErrorMemory.steps` rounds (the synchronous default)."""


class RaceMemory:
    """Measures the error memory of a group of sub-models joined by connections (``members``,
    indices of the race's tracks) and hands it to their step controls.

    ``memory`` is the measured memory [s] (``inf`` until :attr:`ErrorMemory.window` probes exist
    since the start, or since every continuous member reached the group's last event; a member
    already past an event the others have still to reach steps with ``inf`` meanwhile).
    :meth:`accepted` is told of every accepted step of a member and probes when one is due.
    Groups that exchange nothing are probed apart: a probe of one would otherwise call the
    other's sub-models, and each forgets at its own rate.
    """

    def __init__(self, race: Multirate, members: list[int], every: int = PROBE_EVERY) -> None:
        self.race = race
        self.members = list(members)
        self.probes = ErrorMemory(every=every)
        # the continuous members: what a probe steps (a discrete-event model's outputs are held)
        self.live = [race.tracks[k] for k in self.members if not race.tracks[k].discrete]
        self._count = 0
        self._landed: float | None = None  # an event some members have reached, not all
        self._forgotten = -math.inf  # the last event the whole group reached

    @property
    def memory(self) -> float:
        return self.probes.memory

    @property
    def calls(self) -> int:
        """Sub-model calls the probes made (also in each member's calls)."""
        return sum(tr.probes for tr in self.live)

    def reset(self, t0: float, until: float) -> None:
        self.probes.reset(t0, until)
        self._count = 0
        self._landed, self._forgotten = None, -math.inf
        self._share()

    def landed(self, t: float) -> None:
        """A member's step landed on an event at ``t`` (a time event, a discrete model's next
        event, a cut left by another's event): the group forgets once every continuous member
        has reached ``t``. The members reach an event one by one, and the last may come long
        after the first (on the ship plant the chiller stood at the hit at 200 s while the
        network was at 64 s); forgetting at the first landing threw away what the probes
        measured of the dynamics the others still had to cross, and restarted the probing at
        each landing (a probe never crosses an event, so none measures past it before every
        member is there). The members already past it step with no memory meanwhile
        (:meth:`_share`). Landings not yet reached by all are kept as their earliest."""
        if t <= self._forgotten:
            return  # the whole group was there already, and forgot
        self._landed = t if self._landed is None else min(self._landed, t)
        self._reached()
        self._share()

    def _reached(self) -> None:
        if self._landed is not None and self.live \
                and min(tr.t for tr in self.live) >= self._landed:
            self._forgotten, self._landed = self._landed, None
            self.forget()

    def forget(self) -> None:
        """An event: the dynamics after it are not those measured
        (:meth:`ErrorMemory.forget`)."""
        self.probes.forget()
        self._share()

    def _share(self) -> None:
        memory, event = self.probes.memory, self._landed
        for tr in self.live:
            # past an event the rest of the group has yet to reach: what was measured before it
            # says nothing about the dynamics after it
            tr.policy.memory = math.inf if event is not None and tr.t >= event else memory

    def _save(self, t: float) -> dict[int, Any]:
        """Every continuous member's state (each at its own time; ``t`` names the call)."""
        models = self.race.system.models
        return {tr.index: self.race._guard(tr.index, t, models[tr.index].save_state)
                for tr in self.live}

    def accepted(self) -> None:
        """A sub-model's step was accepted: count a round per continuous sub-model's worth of
        steps, and probe when one is due."""
        live = self.live
        if not live or self.probes.every == 0:
            return
        self._reached()
        self._count += 1
        if self._count < len(live):
            return
        self._count = 0
        self.probes.accepted()
        t0 = min(tr.t for tr in live)
        models = self.race.system.models
        # the longest step a member is about to take, within every member's step limits
        h = min(max(tr.h for tr in live),
                *(min(models[tr.index].capabilities.max_step, tr.policy.hmax) for tr in live))
        due = self.probes.due(t0, h)
        self._share()  # measurements made over a shorter horizon than h may have expired
        if due:
            self._probe(live, t0, h)

    def _probe(self, live: list[Track], t0: float, h: float) -> None:
        race = self.race
        end = t0 + (self.probes.steps + 1) * h
        if end > race.until or end > race._kernel.limit() \
                or any(t0 < c <= end for k in self.members for c in race.cuts[k]):
            return  # past the end, or across an event (a discrete model's next): not now
        models = race.system.models
        # the next probe is due `every` rounds from this attempt, whatever comes of it: a probe
        # that fails would otherwise be tried again on every round
        self.probes.attempted(t0)
        now = self._save(t0)
        calls = [tr.calls for tr in live]
        try:
            start = self._align(live, t0)
            if start is not None:
                self._measure(live, t0, h, start)
        except SubModelError as exc:  # a measurement lost, not the run (a hung call ends it)
            if exc.hung:
                raise
        except EndOfSimulation:  # a sub-model that ends the run ahead of it: not now
            pass
        finally:
            for tr, before in zip(live, calls):
                tr.probes += tr.calls - before
            for k, token in now.items():
                race._guard(k, race.tracks[k].t, models[k].restore_state, token)
        self._share()

    def _align(self, live: list[Track], t0: float) -> np.ndarray | None:
        """Every continuous sub-model at ``t0`` (restored and stepped there); the system's
        outputs at ``t0``, or ``None`` where a sub-model kept no state to go back to."""
        race = self.race
        models = race.system.models
        outputs = self._row(t0)
        for tr in live:
            if tr.t == t0:
                continue
            back = [i for i in tr.states if tr.times[i] <= t0]
            if not back:
                return None
            i = max(back, key=lambda j: (tr.times[j], j))
            s = tr.times[i]
            race._guard(tr.index, s, models[tr.index].restore_state, tr.states[i])
            if s < t0:
                inputs, _ = race.inputs_over(tr.index, s, t0 - s)
                y = race.run_step(tr.index, s, t0 - s, inputs)
            else:
                y = tr.rows[i]
            outputs[race.system.output_slices[tr.index]] = y
        return outputs

    def _row(self, t: float) -> np.ndarray:
        """The members' outputs at ``t`` read from their trajectories (no call), in a row of
        the system's outputs; the other groups' columns are 0. Nothing a member reads lies
        outside its group, and another group's trajectory may not reach ``t`` at all (a
        partner rolled back behind an event of its own)."""
        race = self.race
        row = np.zeros(race.system.n_outputs)
        for k in self.members:
            row[race.system.output_slices[k]] = race.values_at(k, np.array([t]))[0]
        return row

    def _history(self, t0: float, h: float, start: np.ndarray) -> list[tuple[float, np.ndarray]]:
        """The points before ``t0`` the probe extrapolates from, ``h`` apart, within the
        segment (no event between), then ``t0`` itself."""
        race = self.race
        lo = max([c for k in self.members for c in race.cuts[k] if c <= t0],
                 default=min(race.tracks[k].times[0] for k in self.members))
        points = []
        for j in range(race.order, 0, -1):
            s = t0 - j * h
            if s >= lo:
                points.append((s, self._row(s)))
        return [*points, (t0, start)]

    def _measure(self, live: list[Track], t0: float, h: float, start: np.ndarray) -> None:
        from cosimstep.multirate import NODES  # the module that imports this one

        race = self.race
        models = race.system.models
        history = self._history(t0, h, start)
        at_t0 = self._save(t0)

        def restore(token: dict[int, Any]) -> None:
            for k, state in token.items():
                race._guard(k, t0, models[k].restore_state, state)

        def step(s: float, length: float, points: tuple[tuple[float, np.ndarray], ...],
                 order: int = race.order) -> np.ndarray:
            path = [p for p in history if p[0] < points[0][0]] + list(points) \
                if points else history
            path = path[-(order + 1):]  # the newest points (one past ``s`` for the corrector)
            coef = taylor_coefficients([p[0] for p in path], np.array([p[1] for p in path]),
                                       s, len(path) - 1)
            values = evaluate_small(coef, (NODES * length).tolist())
            row = path[-1][1].copy()
            system = race.system
            for tr in live:
                k = tr.index
                inputs = system.a[k] * values[:, system.src[k]] + system.b[k]
                row[system.output_slices[k]] = race.run_step(k, s, length, inputs)
            return row

        # the predictor (inputs extrapolated) and the corrector (interpolated through the
        # predictor's end values): they differ by about one coupling error, in the direction
        # coupling errors take — the perturbation ``pc``'s probe starts from
        restore(at_t0)
        y_p = step(t0, h, ())
        predictor = (self._save(t0 + h), y_p)
        restore(at_t0)
        y_c = step(t0, h, ((t0 + h, y_p),), race.order + 1)
        corrector = (self._save(t0 + h), y_c)
        scale = live[0].policy.scale(y_c)
        self.probes.probe(t0 + h, h, corrector, predictor, scale, step, restore)
