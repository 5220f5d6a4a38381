"""A run whose own error estimate cannot vouch for its tolerance is repeated once, tighter.

Step control bounds the error each step makes. Where later dynamics amplify those errors — a
limit cycle's slow build-up before a spike, a phase error met again at every jump of a
relaxation oscillation — no step-by-step decision sees the growth before it has happened, and
``pc`` delivered 15 and 90 × tol on the suite's Van der Pol and Brusselator with status ok
(docs/concepts.md, "Limit cycles"). The run's own global estimate (``error_estimate``) did see
it afterwards: 2.9 and 20.7 × tol.

The classical remedy, "tolerance reduction" (surveyed with the other ways to estimate and act
on a global error by R. D. Skeel, "Thirteen ways to estimate global error", Numer. Math. 48,
1986), is to run again at the tolerance reduced by the factor the estimate missed by: a
controller whose delivered error is proportional to its tolerance then delivers about tol.
Here the repeat happens only when the estimate cannot rule out an error outside the band the
tolerance promises: the estimate is measured within ``1/SPREAD … SPREAD`` × the error on the
suite, and the promise is an error of at most ``BAND`` × tol, so an estimate above
``BAND / SPREAD`` × tol is where the error may lie past the band. Neither constant was fitted
to a problem; both are issue 13's acceptance bands. Below that threshold a repeat would buy
accuracy the estimate cannot tell apart from noise (an estimate 1.06 × tol repeated at
0.95 × tol moved one run's error from 0.54 to 0.096 × tol).

Only controllers whose estimate was measured within that spread steer by it
(a controller's ``trusted_estimate``: ``pc``'s): under the synchronous masters, and under
the multi-rate one where the time shift is most of its estimate (:mod:`~cosimstep.race_drift`,
:func:`tightening`) or the estimate is past ``BAND`` × tol. The estimate that decides is the
run's ``error_estimate``: the summed one by default, the companion's or the re-run's where
``simulate(estimate=...)`` asks for them (both measured closer to the error than the sum on
the suite). The repeat is one, and it is
kept only if it ended ok with an estimate of its own no higher than the first run's
(:func:`keeps_repeat`); where its estimate still exceeds the tolerance asked for
its message says so; and it is never more than ``MOST`` times tighter — a run whose estimate
says it missed by a million is better reported than run for days.
"""

from __future__ import annotations

import copy
import math
from typing import Any

SPREAD = 5.0
"""How far the run's own estimate may lie from the measured error: within 1/5 … 5× (issue 13)."""
BAND = 10.0
"""The error a tolerance promises at most, in units of tol (issue 13's err/tol ≤ 10)."""
THRESHOLD = BAND / SPREAD
"""An estimate above this many tol no longer rules out an error past ``BAND`` × tol."""
MOST = 1e3
"""The repeat's tolerance is at least the run's / ``MOST`` (three decades)."""


def may_repeat(controller: Any) -> bool:
    """Whether a run of ``controller`` is ever repeated: its estimate is one measured within
    ``SPREAD`` of the error (``pc``'s, under any master)."""
    return getattr(controller, "policy", None) is not None \
        and getattr(controller, "trusted_estimate", False)


def tightening(status: str, estimate: float | None, controller: Any, *,
               multirate: bool) -> float | None:
    """The factor to multiply the tolerances by for the repeat, or ``None`` for no repeat.

    ``status``, ``estimate``: the finished run's; ``controller``: the one it ran with;
    ``multirate``: it ran under the multi-rate master, which is repeated only where the time
    shift is the larger part of its estimate (:func:`along_motion`) or where the estimate
    itself is past ``BAND`` × tol: the run says it broke the promise, whatever the estimate is
    made of. Why the shift otherwise: where the rule was built, the multi-rate runs past
    10 × tol were such runs, and repeating on the plain sum as well bought accuracy the band
    did not ask for on runs that were in it (docs/concepts.md, "The multi-rate estimate with a
    time shift, and its repeat")."""
    if status != "ok" or estimate is None or not may_repeat(controller):
        return None
    ratio = estimate / controller.policy.tol
    if not ratio > THRESHOLD or (multirate and not along_motion(controller)
                                 and not ratio > BAND):
        return None
    return max(1.0 / ratio, 1.0 / MOST)


def keeps_repeat(status: str, first: float, repeat: float | None) -> bool:
    """Whether the repeat is the result: it ended ok with an estimate of its own (``repeat``)
    no higher than the first run's (``first``) — the only judge there is without a
    reference. A missing or NaN estimate is not kept."""
    return status == "ok" and repeat is not None and repeat <= first


def calibrated(estimate: float | None, first_estimate: float | None,
               first_error: float | None) -> float | None:
    """The repeat's estimate scaled by how far the first run's own estimate was from that
    run's error as the repeat measures it (:func:`cosimstep.pair.difference`); ``None``
    where one of the three is missing, not finite, or (the first run's two) not positive.

    Why: the summed estimate's local parts are right to a few times (docs/concepts.md,
    "Where the summed estimate and the error part"), but how the errors add up — fade,
    cancel, or return at every spike of a limit cycle — is a property of the system that the
    sum does not know and the pair has measured: the first run made its errors, the repeat
    showed what they came to. The repeat makes the same kind of errors at a smaller size, so
    the ratio carries over. Measured on the suite and the holdout systems (both masters, 390
    cells, of which 96 repeated): estimates outside [0.2, 5] × the error 73 → 65, below 0.2
    11 → 10; on four systems built afterwards for the check, 9 → 0 of the 15 kept repeats.
    The decision to keep the repeat is not made on it but on the repeat's own estimate, as
    before (:func:`keeps_repeat`)."""
    if estimate is None or first_estimate is None or first_error is None \
            or not (math.isfinite(estimate) and 0 < first_estimate < math.inf
                    and 0 < first_error < math.inf):
        return None
    return estimate * first_error / first_estimate


def scaled(controller: Any, factor: float) -> Any:
    """A copy of ``controller`` (not yet run) with its tolerances multiplied by ``factor``."""
    twin = copy.deepcopy(controller)
    policy = twin.policy
    policy.tol *= factor
    policy.atol = None if policy.atol is None else policy.atol * factor
    policy.rtol = None if policy.rtol is None else policy.rtol * factor
    return twin


def along_motion(controller: Any) -> bool:
    """Whether the time shift carries more than half of the finished run's summed estimate
    (:mod:`~cosimstep.controllers.drift`, the controller's own, whichever estimate the run
    reports; under the multi-rate master :mod:`~cosimstep.race_drift`'s, handed to the
    controller by the run): that estimate is above twice the plain sum of the local
    estimates. At the estimate's largest the rest is at most that sum — except for shifts an
    event turned into ordinary errors, which were shifts before it — so the shift, the error
    along the motion, is the larger part. ``controller``: the one the run used."""
    value = getattr(controller, "error_estimate", None)
    summed = getattr(controller, "summed_estimate", None)
    return value is not None and summed is not None and value > 2.0 * summed


def for_repeat(controller: Any, factor: float, forget: bool) -> Any:
    """The repeat's controller: ``controller`` (not yet run) at ``factor`` × its tolerances;
    with ``forget`` (:func:`along_motion` of the first run), sharing them over the whole run,
    its error memory unmeasured (no probes).

    Why: the step control planned for an error of about ``tol`` by sharing the tolerance over
    the measured memory ``M``. A probe measures how fast a perturbation fades, and on an
    attracting slow branch of a relaxation oscillation it sees the part across the motion fade
    and reads a short memory, while the part along the motion, a time shift, never fades and
    returns at the next jump at the jump's speed. Where that shift carries most of the first
    run's summed estimate, the plan failed in the part the memory does not describe: a repeat
    that trusts the probes again repeats it, and its error need not even fall with tol
    (FitzHugh–Nagumo at 1e-3, 11.8 × tol, repeated at tol / 2.6 with the probes: 26.5 × the
    first tol; without them 3.7 ×). Without a memory every error is taken to persist, as the
    step control assumes before any memory is measured. Where the plain sum itself carries the
    estimate (a settling system whose bold step control overspent, the pump example with
    ``trend``), the memory stands: dropping it there made the repeat 0.004 × tol instead of
    in the band (docs/concepts.md, "A repeat without the error memory")."""
    twin = scaled(controller, factor)
    probe = getattr(twin, "probe", None)
    if forget and probe is not None and probe.every:
        twin.probe = type(probe)(every=0, steps=probe.steps, window=probe.window,
                                 per_run=probe.per_run)
        twin.measures_memory = False
        # they act only where a measured memory shows the system settling: off, so that the
        # repeat's stored settings are ones a controller can be made with
        twin.policy.trend = twin.policy.unbiased = False
    return twin


def note(tol: float, estimate: float, calls: int, factor: float, forget: bool) -> str:
    """What the repeat's message adds: why it ran, and what the first run cost; ``forget``:
    it runs without the error memory (:func:`for_repeat`)."""
    return (f"repeated at tol {tol * factor:.3g}{' without the error memory' if forget else ''}"
            f": at tol {tol:.3g} the run estimated its own "
            f"error at {estimate / tol:.3g} x tol, past {THRESHOLD:g} x tol, where more than "
            f"{BAND:g} x tol cannot be ruled out ({calls} calls)")


__all__ = ["BAND", "MOST", "SPREAD", "THRESHOLD", "along_motion", "calibrated", "for_repeat",
           "keeps_repeat", "may_repeat", "note", "scaled", "tightening"]
