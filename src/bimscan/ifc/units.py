"""Length units a model may be read in (``--length-unit``), in metres per unit."""

from __future__ import annotations

LENGTH_UNITS: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001, "ft": 0.3048, "in": 0.0254}

# A model without a length unit whose extent, read in metres, exceeds this is read as millimetres:
# no building is a kilometre across, while millimetre exports of houses are 10-100 "km" in metres.
GUESS_MM_ABOVE_M = 1000.0


def unit_name(metres: float) -> str:
    """The LENGTH_UNITS name of a unit, or '<x> m' for another."""
    for name, value in LENGTH_UNITS.items():
        if abs(value - metres) <= 1e-12 * value:
            return {"m": "metres", "cm": "centimetres", "mm": "millimetres", "ft": "feet", "in": "inches"}[name]
    return f"units of {metres:g} m"
