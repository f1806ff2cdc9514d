"""Exception hierarchy. The library raises these and never prints or exits; only ``dfc.cli``
turns them into one-line messages and exit codes.

Each error inherits from the built-in it refines, so callers may catch either
(``except ValueError`` keeps working)."""


class DfcError(Exception):
    """Base class of every error dfc raises on purpose."""


class SettingsError(DfcError, ValueError):
    """A setting breaks its rule (``dfc.settings``): the message names the setting and states the rule."""


class CurveError(DfcError, ValueError):
    """A curves file (SVG / JSON / diffusion-curve XML) is unreadable or malformed."""


class MeshError(DfcError, ValueError):
    """A triangulation cannot be built or breaks one of its invariants (see ``Mesh.validate``)."""


class TriangleBudgetError(MeshError):
    """``max_triangles`` is below what the curves force; ``needed`` is that smallest triangle count."""

    def __init__(self, message: str, needed: int):
        super().__init__(message)
        self.needed = int(needed)


class InputError(DfcError, ValueError):
    """An image or sample input is unreadable or unusable (NaN pixels, mismatched domain, ...)."""


class TargetBytesError(InputError):
    """A byte target is below the smallest file the curves allow with the encode's settings."""


class ResidualBytesError(InputError):
    """A residual's byte budget is below its smallest stream (``dfc.io.residual.encode_residual``)."""


class FormatError(DfcError, ValueError):
    """A ``.dfield`` file is truncated, corrupt, hostile or of an unsupported version."""


class ExtraError(DfcError, ImportError):
    """An optional dependency is not installed; the message names the ``pip install 'dfc[extra]'`` that adds it."""
