"""dfc — the discontinuity-aware field codec."""

from .curves import Curves, SideValues, read_curves
from .errors import CurveError, DfcError, FormatError, InputError, MeshError
from .mesh import Mesh

__all__ = [
    "Curves",
    "SideValues",
    "read_curves",
    "Mesh",
    "DfcError",
    "CurveError",
    "MeshError",
    "InputError",
    "FormatError",
]
__version__ = "0.1.0"
