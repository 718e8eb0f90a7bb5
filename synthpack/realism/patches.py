"""Square in-slice patches wholly inside a mask: the realism report's name for `synthpack.source.patches`."""

from ..source.patches import patch_corners, take_patches

__all__ = ["patch_corners", "take_patches"]
