"""The run kernel: a time-ordered heap of actors, in the spirit of SimPy.

Every way of advancing a coupled system in time is expressed as *actors*: something that stands
at a time and, when it is its turn, acts from there. The kernel always lets the actor that is
farthest behind act next (thesis appendix C's race), so

- a synchronous co-simulation (one communication step for every sub-model) is one actor;
- the multi-rate master is one actor per sub-model, each with its own step;
- a sub-model moved back in time by a rollback is *woken*: queued again at its new time; a
  newer entry supersedes the older ones still in the heap.

An actor acts "up to a limit": the end of the run, or the time of the next discrete actor (a
discrete-event sub-model, :mod:`cosimstep.events`, whose next event time may change after each
event). A synchronous actor alone in the heap runs its whole loop in one turn (the fixed-step
path keeps its speed); with discrete actors it stops on each of their times, they act (rank -1:
before anyone else at the same time), and it goes on.
When the heap is empty the kernel asks ``settle`` whether anything is left to redo (the
multi-rate master's last verification may roll sub-models back) and runs again if so.
"""

from __future__ import annotations

import copy
import heapq
import itertools
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable


class BudgetExceeded(Exception):
    """The run spent a budget its user set (wall time, calls): it ends ``timed_out``."""


class Budget:
    """Whole-run limits, checked by the actors as they go (``None``: no limit)."""

    def __init__(self, max_wall: float | None = None, max_calls: int | None = None) -> None:
        for name, value in (("max_wall", max_wall), ("max_calls", max_calls)):
            if value is not None and not value > 0:
                raise ValueError(f"`{name}` must be positive, got {value}")
        self.max_wall, self.max_calls = max_wall, max_calls
        self._start = time.perf_counter()
        self._before = 0  # calls spent by earlier runs for the same result (:meth:`after`)

    def __bool__(self) -> bool:
        return self.max_wall is not None or self.max_calls is not None

    def after(self, calls: int) -> Budget:
        """What is left for a further run once ``calls`` are spent by others (the wall clock
        runs on from this budget's start): a run given it checks its own calls against the
        rest, so that runs made for one result (a re-run estimate's looser twin, a repeat at
        a tighter tol) share one budget. Nothing left: its first check ends it."""
        left = copy.copy(self)
        left.max_calls = None if self.max_calls is None else self.max_calls - calls
        left._before = self._before + calls
        return left

    def affords(self, calls: int, wall: float) -> bool:
        """Whether this budget could pay for a run of ``calls`` calls and ``wall`` seconds."""
        if self.max_calls is not None and self.max_calls < calls:
            return False
        return self.max_wall is None or \
            self.max_wall - (time.perf_counter() - self._start) >= wall

    def check(self, calls: int) -> None:
        """Raise :class:`BudgetExceeded` if ``calls`` or the wall time since the start is over."""
        if self.max_calls is not None and calls >= self.max_calls:
            before = f", {self._before} of them by the runs before this one" if self._before \
                else ""
            raise BudgetExceeded(f"the budget of {self.max_calls + self._before} calls is spent "
                                 f"({calls + self._before} calls{before})")
        if self.max_wall is not None and time.perf_counter() - self._start >= self.max_wall:
            raise BudgetExceeded(f"the wall-time budget of {self.max_wall:g} s is spent")


class Actor(ABC):
    """Something that advances in time when the kernel gives it its turn."""

    name: str = "actor"
    rank: int = 0  # among actors at the same time, the lower rank acts first
    bounds: bool = False  # a discrete actor: no other actor may step past its time

    @property
    @abstractmethod
    def time(self) -> float:
        """Where it stands: its next action starts here."""

    @property
    def finished(self) -> bool:
        """Whether it has nothing more to do (it is not queued again)."""
        return False

    @abstractmethod
    def act(self, limit: float) -> None:
        """Advance from :attr:`time`, not past ``limit``; at least one step unless finished."""


class Kernel:
    """Runs actors until every one is finished (or one of them raises)."""

    def __init__(self, until: float) -> None:
        self.until = until
        self._heap: list[tuple[float, int, int, Actor]] = []
        self._order = itertools.count()  # ties of time and rank: first queued acts first
        self._latest: dict[int, int] = {}  # id(actor) -> its newest entry (others are stale)
        self._bounds: list[Actor] = []  # the discrete actors

    def limit(self) -> float:
        """How far an actor may go this turn: the end, or the next discrete actor's time."""
        return min([self.until, *(a.time for a in self._bounds if not a.finished)])

    def add(self, actor: Actor) -> None:
        """Queue ``actor`` at its time (again, after a rollback moved it back)."""
        if actor.bounds and all(a is not actor for a in self._bounds):
            self._bounds.append(actor)
        if not actor.finished:
            ticket = next(self._order)
            self._latest[id(actor)] = ticket
            heapq.heappush(self._heap, (actor.time, actor.rank, ticket, actor))

    wake = add

    def run(self, settle: Callable[[], Iterable[Actor]] | None = None) -> None:
        """Turns until the heap is empty; then ``settle()`` names actors to run again."""
        while True:
            while self._heap:
                _, _, ticket, actor = heapq.heappop(self._heap)
                if ticket != self._latest.get(id(actor)) or actor.finished:
                    continue  # superseded (a rollback queued it again), or already done
                actor.act(self.limit())
                self.add(actor)
            again = list(settle()) if settle is not None else []
            if not again:
                return
            for actor in again:
                self.add(actor)


__all__ = ["Actor", "Budget", "BudgetExceeded", "Kernel"]
