"""The hazard step: Dem2Hazard on a DEM's layers."""

from __future__ import annotations

from ..algorithms.dem2hazard import HazardParams, dem2hazard_layers
from ..engine import step
from ..grid import Layers


@step("hazard_layers", outputs={"layers": "Layers"}, settings=HazardParams)
def hazard_layers(layers: Layers, settings: HazardParams | None = None) -> Layers:
    """Dem2Hazard on the ``dem`` layer: slope, step, roughness, hazard, traversability."""
    return dem2hazard_layers(layers, settings)
