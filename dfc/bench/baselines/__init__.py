"""Equal-size baselines for ``dfc bench``: each a ``Baseline`` module sized to a byte budget (the
physics-informed ones, ``Siren`` and ``TanhMLP``, keep the paper's fixed architectures and report their size).

``BASELINES`` maps a method's key in benchmark results to its class.
"""

from .base import Baseline, fit_baseline
from .hashgrid import HashGrid
from .raster import Raster
from .relu_field import ReluField
from .siren import Siren
from .tanh_field import TanhField
from .tanh_mlp import TanhMLP

__all__ = ["BASELINES", "Baseline", "HashGrid", "Raster", "ReluField", "Siren", "TanhField", "TanhMLP", "fit_baseline"]

BASELINES = {cls.name: cls for cls in (HashGrid, ReluField, Raster, TanhField, Siren, TanhMLP)}
