"""Equal-size baselines for ``dfc bench``: each a ``Baseline`` module sized to a byte budget.

``BASELINES`` maps a method's key in benchmark results to its class.
"""

from .base import Baseline, train
from .hashgrid import HashGrid
from .raster import Raster
from .relu_field import ReluField

__all__ = ["BASELINES", "Baseline", "HashGrid", "Raster", "ReluField", "train"]

BASELINES = {cls.name: cls for cls in (HashGrid, ReluField, Raster)}
