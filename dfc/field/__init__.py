"""The discontinuity-aware feature field (docs/design.md §5): point location, bank layout, side test,
interpolation, and the ``FeatureField`` module that ties them together."""

from .feature_field import FeatureField
from .layout import Layout, build_layout

__all__ = ["FeatureField", "Layout", "build_layout"]
