"""Split a bi-prism capture into its reference (left) and other (right) half-images.

The split is at the rig's apex column (:attr:`BiPrismRig.reference_width` columns go to the reference
half), not blindly at W / 2: with ``prism_offset_x_mm`` != 0 the apex, and so the split, moves.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import nn

from prismstereo.errors import ShapeError, check_shape
from prismstereo.geometry.rig import BiPrismRig

__all__ = ["Halves", "SplitImage"]


class Halves(NamedTuple):
    """The two half-images of a capture.

    Attributes:
        reference: (B, C, H, W_ref) the left half (u < apex column), the reference view.
        other: (B, C, H, W - W_ref) the right half.
    """

    reference: torch.Tensor
    other: torch.Tensor


class SplitImage(nn.Module):
    """Split (B, C, H, W) captures at the rig's apex column into reference and other half.

    Args:
        rig: the rig; its image size is checked against every input.

    Example:
        >>> halves = SplitImage(thesis_setup1())(torch.rand(2, 1, 768, 1024))
        >>> halves.reference.shape, halves.other.shape
        (torch.Size([2, 1, 768, 512]), torch.Size([2, 1, 768, 512]))
    """

    def __init__(self, rig: BiPrismRig) -> None:
        super().__init__()
        self.width, self.height = rig.image_width, rig.image_height
        self.split = rig.reference_width

    def forward(self, image: torch.Tensor) -> Halves:
        """Split ``image`` (B, C, H, W); raises :class:`ShapeError` if H, W differ from the rig's."""
        check_shape(image, ["B", "C", "H", "W"], "image")
        if image.shape[-2:] != (self.height, self.width):
            raise ShapeError(
                f"image is {image.shape[-1]}x{image.shape[-2]} px but the rig's sensor is {self.width}x{self.height}"
            )
        return Halves(image[..., : self.split], image[..., self.split:])
