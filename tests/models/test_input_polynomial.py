"""The ODE adapter's input polynomial: the same values as the NumPy form, bit for bit.

``InputPolynomial`` evaluates the inputs a right-hand side sees on Python floats (issue 15,
"same work, faster"); it must change no value of any run, so it is compared with
``_taylor`` — the form every other path (the re-expansion at a step's end, the model-exchange
FMU adapter) still uses — on random inputs of every size and scale, derivative rows left at
zero included.
"""

from __future__ import annotations

import numpy as np

from cosimstep.adapters.ode import InputPolynomial, _taylor


def test_the_input_polynomial_is_bit_for_bit_the_numpy_form() -> None:
    rng = np.random.default_rng(7)
    compared = 0
    for inputs in range(5):
        for rows in (3, 4):
            for used in range(rows + 1):
                for _ in range(300):
                    u = rng.normal(size=inputs) * 10.0 ** rng.uniform(-6, 6)
                    du = np.zeros((rows, inputs))
                    du[:used] = rng.normal(size=(used, inputs)) * 10.0 ** rng.uniform(-6, 6)
                    dt = rng.uniform(-1, 1) * 10.0 ** rng.uniform(-9, 1)
                    expected = _taylor(u, du, dt)
                    got = InputPolynomial(u, du)(dt)
                    assert got.dtype == expected.dtype and got.shape == expected.shape
                    assert [v.hex() for v in got.tolist()] == \
                        [v.hex() for v in expected.tolist()], (inputs, rows, used, dt)
                    compared += 1
    assert compared == 5 * (4 + 5) * 300
    # the sign of zero too: -0.0 plus a zero term is +0.0 (arctan2 tells them apart)
    u, du = np.array([-0.0, 1.0]), np.array([[-2.0, 0.5], [0.0, 0.0], [0.0, 0.0]])
    assert [v.hex() for v in InputPolynomial(u, du)(0.0).tolist()] == \
        [v.hex() for v in _taylor(u, du, 0.0).tolist()]
