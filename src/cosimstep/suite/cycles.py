"""Limit cycles: oscillators that forget amplitude errors but never phase errors.

On a stable limit cycle a perturbation across the cycle fades, while one along it — a shift in
phase — stays, and where the motion runs through a fast stretch (a jump of a relaxation
oscillation, the spike of a chemical oscillator) a small shift in time is a large difference in
value. A step control that sums local errors sees neither: the errors it sums are those of the
slow stretches, and the error it delivers is set at the fast ones. Both problems split the two
states into two sub-models, as a user coupling two tools would.
"""

from __future__ import annotations

import numpy as np

from cosimstep.reference import Reference
from cosimstep.suite.base import scalar_pair
from cosimstep.system import System

VDP_SOURCE = ("B. van der Pol (1926), 'On relaxation-oscillations', Phil. Mag. 2(11):978–992; "
              "in Liénard's coordinates as in E. Hairer, S. P. Nørsett, G. Wanner (1993), "
              "'Solving Ordinary Differential Equations I', 2nd ed., Springer, section I.16 "
              "(our μ = 3 and split)")
BRUSSELATOR_SOURCE = ("R. Lefever, G. Nicolis (1971), 'Chemical instabilities and sustained "
                      "oscillations', J. Theor. Biol. 30:267–284; the test problem BRUS of "
                      "E. Hairer, S. P. Nørsett, G. Wanner (1993), 'Solving Ordinary "
                      "Differential Equations I', 2nd ed., Springer, section II.10 (A = 1, B = 3, "
                      "our split)")


def van_der_pol(mu: float = 3.0) -> tuple[System, Reference]:
    """Van der Pol's oscillator in Liénard's coordinates, x' = μ (x − x³/3 − y), y' = x / μ,
    split x | y, from (2, 0), 12 s.

    Time scales: with μ = 3 the cycle (period about 8.9 s) creeps along its two slow branches
    and jumps between them in about half a second. What can go wrong: the slow branches
    attract, so an error across them fades (a short probe reads it as a short error memory),
    while a phase error lives on and returns, multiplied by the jump's slope, at every jump.
    """
    def fx(t: float, s: np.ndarray, u: np.ndarray, _: object) -> np.ndarray:
        return np.array([mu * (s[0] - s[0] ** 3 / 3.0 - u[0])])

    def fy(t: float, s: np.ndarray, u: np.ndarray, _: object) -> np.ndarray:
        return np.array([u[0] / mu])

    def whole(t: float, s: np.ndarray, u: np.ndarray, _: object) -> np.ndarray:
        return np.array([mu * (s[0] - s[0] ** 3 / 3.0 - s[1]), s[0] / mu])

    return scalar_pair(fx, fy, whole, (2.0, 0.0), ("x", "y"))


def brusselator(a: float = 1.0, b: float = 3.0) -> tuple[System, Reference]:
    """The Brusselator, x' = A + x² y − (B + 1) x, y' = B x − x² y, split x | y, from (1, 1),
    20 s.

    Time scales: with B = 3 > 1 + A² the steady state is unstable and the cycle (period about
    7.2 s) alternates a slow build-up of ``y`` with a spike of ``x`` (above 1.5 for about
    1.5 s). What
    can go wrong: through the build-up small differences grow before the spike (local errors
    there come out 50–100 times larger at it), and the long steps the slow stretch allows make
    those errors.
    """
    def fx(t: float, s: np.ndarray, u: np.ndarray, _: object) -> np.ndarray:
        return np.array([a + s[0] ** 2 * u[0] - (b + 1.0) * s[0]])

    def fy(t: float, s: np.ndarray, u: np.ndarray, _: object) -> np.ndarray:
        return np.array([b * u[0] - u[0] ** 2 * s[0]])

    def whole(t: float, s: np.ndarray, u: np.ndarray, _: object) -> np.ndarray:
        return np.array([a + s[0] ** 2 * s[1] - (b + 1.0) * s[0], b * s[0] - s[0] ** 2 * s[1]])

    return scalar_pair(fx, fy, whole, (1.0, 1.0), ("x", "y"))
