"""The hazard step: Dem2Hazard on a DEM's layers."""

from __future__ import annotations

from typing import Any

from ..algorithms.dem2hazard import dem2hazard_layers
from ..engine import step
from ..grid import Layers


@step("hazard_layers", outputs={"layers": "Layers"})
def hazard_layers(layers: Layers, params: dict[str, Any] | None = None) -> Layers:
    """Dem2Hazard on the ``dem`` layer: slope, step, roughness, hazard, traversability."""
    return dem2hazard_layers(layers, params)
