"""``pc``'s input ratio, computed from one stack of values (issue 15, "same work, faster"),
is bit for bit what one Taylor fit per curve and one evaluation per node give — the form it
replaced, written out here as the reference. Any change of rounding in the ratio moves the
step sizes, and with them a whole adaptive run."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from cosimstep.controllers.coupling import _NODES, PredictorCorrector
from cosimstep.extrapolation import evaluate, taylor_coefficients


def reference_ratio(controller: PredictorCorrector, ctx: SimpleNamespace, t: float, h: float,
                    q: int, y_p: np.ndarray, y_c: np.ndarray) -> np.ndarray:
    ratio = np.ones(len(ctx.names))
    cols = np.flatnonzero(ctx.consumed & ~ctx.discrete)
    fresh = ~ctx.predicted[cols] | ctx.iterated
    times, hist = list(ctx.times), ctx.history[:, cols]

    def curve(n_old: int, end: np.ndarray | None) -> np.ndarray:
        pts = times[len(times) - n_old:] + ([t + h] if end is not None else [])
        rows = hist[len(hist) - n_old:]
        if end is not None:
            rows = np.vstack([rows, end[cols]])
        c = taylor_coefficients(pts, rows, t, len(pts) - 1)
        return np.array([evaluate(c, dt) for dt in h * _NODES])

    u_p = np.where(fresh, curve(q, y_p), curve(q + 1, None))
    u_c = np.where(fresh, curve(q + 1, y_c), curve(q + 1, y_p))
    u_best = curve(q + 2, y_c)
    scale = controller.policy.scale(hist[-1])
    moved, left, along = np.zeros(len(ratio)), np.zeros(len(ratio)), np.zeros(len(ratio))
    moved[cols] = np.mean(np.abs(u_p - u_c), axis=0) / scale
    left[cols] = np.mean(np.abs(u_best - u_c), axis=0) / scale
    along[cols] = np.sum((u_c - u_best) * (u_c - u_p), axis=0) / scale ** 2
    for src, own in ctx.readers:
        if src.size == 0:
            ratio[own] = 0.0
            continue
        m = float(np.max(moved[src]))
        if m > 0:
            ratio[own] = float(np.max(left[src])) / m * (-1.0 if np.sum(along[src]) < 0 else 1.0)
    return ratio


def test_the_input_ratio_is_bit_for_bit_the_per_curve_form() -> None:
    rng = np.random.default_rng(11)
    controller = PredictorCorrector(tol=1e-4)
    compared = 0
    for _ in range(400):
        q = int(rng.integers(0, 3))
        n_out = 6
        stored = q + 2 + int(rng.integers(0, 3))
        t = float(rng.uniform(0, 100))
        steps = rng.uniform(0.2, 1.0, size=stored) * 10.0 ** rng.uniform(-5, -1)
        times = list(t - np.cumsum(steps)[::-1] + steps[-1])
        times[-1] = t
        history = rng.normal(size=(stored, n_out)) * 10.0 ** rng.uniform(-3, 3)
        h = float(steps.mean() * rng.uniform(0.5, 2.0))
        y_p = history[-1] + rng.normal(size=n_out) * h
        y_c = y_p + rng.normal(size=n_out) * h * 1e-3
        ctx = SimpleNamespace(
            names=[f"y{i}" for i in range(n_out)], times=times, history=history,
            consumed=rng.random(n_out) < 0.8, discrete=rng.random(n_out) < 0.1,
            held=np.zeros(n_out, dtype=bool),
            predicted=rng.random(n_out) < 0.5, iterated=bool(rng.random() < 0.2),
            readers=[(np.array([3, 4, 5]), slice(0, 3)), (np.array([0, 1, 2]), slice(3, 6)),
                     (np.array([], dtype=int), slice(6, 6))])
        if not (ctx.consumed & ~ctx.discrete).any():
            continue
        got = controller._input_ratio(ctx, t, h, q, y_p, y_c)
        expected = reference_ratio(controller, ctx, t, h, q, y_p, y_c)
        assert [v.hex() for v in got.tolist()] == [v.hex() for v in expected.tolist()]
        compared += 1
    assert compared > 350


def test_the_ratio_has_the_sign_of_the_input_error_left_in_the_corrector() -> None:
    """One receiver reading one extrapolated input: the corrector's input curve ``u_c`` (a
    cubic through the last three points and the new value) against the true input, over the
    step, along the predictor's change ``u_c − u_p``. On 2,000 smooth inputs (two sines, steps
    of 0.02–0.4 rad of the faster) with exact new values the ratio's sign is that of
    ``⟨u_c − u, u_c − u_p⟩`` every time; a ratio without a sign is right on 43 % of them."""
    rng = np.random.default_rng(5)
    controller = PredictorCorrector(tol=1e-4)
    agree = positive = 0
    cases = 2000
    for _ in range(cases):
        w, phi = rng.uniform(0.5, 2.0), rng.uniform(0.0, 2.0 * np.pi)

        def u(s: float, w: float = w, phi: float = phi) -> float:
            return math.sin(w * s + phi) + 0.3 * math.sin(2.7 * w * s)

        h = rng.uniform(0.02, 0.4) / w
        times = [k * h for k in range(4)]
        t = times[-1]
        history = np.array([[u(s), 0.0] for s in times])
        new = np.array([u(t + h), 0.0])
        ctx = SimpleNamespace(
            names=["u", "y"], times=times, history=history, consumed=np.array([True, False]),
            discrete=np.zeros(2, dtype=bool), held=np.zeros(2, dtype=bool),
            predicted=np.array([True, False]), iterated=False,
            readers=[(np.array([0]), slice(1, 2)), (np.array([], dtype=int), slice(0, 1))])
        ratio = controller._input_ratio(ctx, t, h, 2, new, new)[1]

        def curve(pts: list[float], values: list[float], t: float = t,
                  h: float = h) -> np.ndarray:
            c = taylor_coefficients(pts, np.array(values)[:, None], t, len(pts) - 1)
            return np.array([evaluate(c, dt)[0] for dt in h * _NODES])

        u_p = curve(times[1:], list(history[1:, 0]))
        u_c = curve([*times[1:], t + h], [*history[1:, 0], new[0]])
        truth = np.array([u(t + dt) for dt in h * _NODES])
        left_along = float(np.sum((u_c - truth) * (u_c - u_p)))
        agree += (ratio < 0) == (left_along < 0)
        positive += left_along > 0
    assert agree == cases
    assert 0.3 < positive / cases < 0.6
