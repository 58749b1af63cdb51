"""The box of the frame a window's flow covers, and its flow grid: maps move between the box's grid and
the whole frame through it."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class Roi:
    """The box the second pass measures and its flow grid.

    Attributes
    ----------
    x, y, width, height : int
        The box in input pixels.
    grid_shape : (h, w)
        Its flow grid.
    frame_shape : (H, W)
        The input frame's size.
    """

    x: int
    y: int
    width: int
    height: int
    grid_shape: tuple[int, int]
    frame_shape: tuple[int, int]

    @property
    def pixel_scale(self) -> float:
        """Input pixels per grid pixel."""
        return self.width / self.grid_shape[1]

    @property
    def whole_frame(self) -> bool:
        return (self.x, self.y, self.width, self.height) == (0, 0, self.frame_shape[1], self.frame_shape[0])

    def crop(self, image: NDArray[np.generic]) -> NDArray[np.generic]:
        """The box of an input-resolution image (H, W, ...)."""
        return image[self.y : self.y + self.height, self.x : self.x + self.width]

    def on_grid(self, gray: NDArray[np.uint8]) -> NDArray[np.uint8]:
        """A grey frame (H, W) cropped to the box and area-averaged onto its grid."""
        crop = self.crop(gray)
        h, w = self.grid_shape
        if crop.shape[:2] == (h, w):
            return np.ascontiguousarray(crop)
        return np.asarray(cv2.resize(crop, (w, h), interpolation=cv2.INTER_AREA), np.uint8)

    def to_frame(self, grid_map: NDArray[np.generic], *, fill: float = 0) -> NDArray[np.generic]:
        """A map on the box's grid (h, w) as a map of the whole frame (H, W): resized into the box
        (nearest), ``fill`` outside it."""
        H, W = self.frame_shape
        out = np.full((H, W), fill, dtype=grid_map.dtype)
        inside = grid_map
        if grid_map.shape != (self.height, self.width):
            inside = cv2.resize(grid_map, (self.width, self.height), interpolation=cv2.INTER_NEAREST)
        out[self.y : self.y + self.height, self.x : self.x + self.width] = inside
        return out

    def from_frame(self, frame_map: NDArray[np.generic]) -> NDArray[np.generic]:
        """A map of the whole frame (H, W) on the box's grid (nearest)."""
        crop = self.crop(frame_map)
        h, w = self.grid_shape
        if crop.shape[:2] == (h, w):
            return np.ascontiguousarray(crop)
        return np.asarray(cv2.resize(crop, (w, h), interpolation=cv2.INTER_NEAREST))

    def describe(self) -> dict[str, object]:
        return {
            "box_px": [self.x, self.y, self.width, self.height],
            "grid": [self.grid_shape[1], self.grid_shape[0]],
            "pixel_scale": round(self.pixel_scale, 4),
        }

    @classmethod
    def whole(cls, frame_shape: tuple[int, int], grid_shape: tuple[int, int]) -> Roi:
        """The whole frame on ``grid_shape``."""
        return cls(0, 0, frame_shape[1], frame_shape[0], grid_shape, frame_shape)


__all__ = ["Roi"]
