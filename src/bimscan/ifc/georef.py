"""A model's georeferencing: where its engineering frame lies in map coordinates.

IFC4 and IFC4X3 models may carry an ``IfcMapConversion`` (the model's origin at ``Eastings``,
``Northings``, ``OrthogonalHeight`` of a projected CRS, its x axis along ``XAxisAbscissa``,
``XAxisOrdinate``, and a ``Scale`` from the project's unit to the CRS's). A site scan exported in
map coordinates then lies where the conversion puts the model, which ``bimscan align`` takes as
one more candidate pose and as the tie-breaker between the poses of a symmetric plan.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bimscan.ifc.schedule import open_model


def read_map_conversion(path: str | Path) -> np.ndarray | None:
    """(4, 4) rigid matrix model frame (metres, as bimscan loads it) -> map coordinates (metres), or
    None when the model has no map conversion, or one bimscan cannot take as rigid (a scale other
    than the project unit's, so the map is not in metres)."""
    import ifcopenshell.util.unit

    model = open_model(path)
    if model.schema == "IFC2X3":
        return None
    conversions = model.by_type("IfcMapConversion")
    if not conversions:
        return None
    conversion = conversions[0]
    metres_per_unit = ifcopenshell.util.unit.calculate_unit_scale(model)
    scale = float(getattr(conversion, "Scale", None) or 1.0)
    # Scale takes project units to the map's; bimscan's model frame is in metres already, so the map
    # is in metres (and the conversion rigid) when Scale equals the metres per project unit
    if not np.isclose(scale / metres_per_unit, 1.0, rtol=1e-6):
        return None
    abscissa = float(getattr(conversion, "XAxisAbscissa", None) or 1.0)
    ordinate = float(getattr(conversion, "XAxisOrdinate", None) or 0.0)
    norm = float(np.hypot(abscissa, ordinate))
    if norm == 0:
        return None
    c, s = abscissa / norm, ordinate / norm
    matrix = np.eye(4)
    matrix[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    matrix[:3, 3] = [float(conversion.Eastings), float(conversion.Northings),
                     float(getattr(conversion, "OrthogonalHeight", None) or 0.0)]
    return matrix
