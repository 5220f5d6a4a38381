"""Unit conversion between connected ports (thesis 3.2: "data modification").

Pint does the work; it is imported only when two connected ports actually differ in unit, so
runs of unit-consistent systems do not pay for loading it.
"""

from __future__ import annotations

from functools import lru_cache

DIMENSIONLESS = {"", "1", "-"}


class UnitError(ValueError):
    """Two units cannot be converted into each other (or a unit is unknown)."""


@lru_cache(maxsize=1)
def _registry():  # pragma: no cover - trivial
    import pint

    return pint.UnitRegistry(autoconvert_offset_to_baseunit=True)


def _norm(unit: str) -> str:
    return "dimensionless" if unit.strip() in DIMENSIONLESS else unit.strip()


@lru_cache(maxsize=256)
def conversion(source: str, target: str) -> tuple[float, float]:
    """Return ``(scale, offset)`` with ``target_value = scale * source_value + offset``.

    Raises :class:`UnitError` when the units are unknown or of different dimensions.
    """
    if _norm(source) == _norm(target):
        return 1.0, 0.0
    ureg = _registry()
    try:
        q0 = ureg.Quantity(0.0, _norm(source)).to(_norm(target)).magnitude
        q1 = ureg.Quantity(1.0, _norm(source)).to(_norm(target)).magnitude
    except Exception as exc:  # pint raises several types; all mean "cannot convert"
        raise UnitError(f"cannot convert '{source}' to '{target}': {exc}") from exc
    return float(q1 - q0), float(q0)
