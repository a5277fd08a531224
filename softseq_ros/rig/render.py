"""
Side-view image of the actuator's backbone (what the rig's camera sees, like the paper's Fig. 7).

Pure numpy, no ROS. The view looks at the bending plane x-z from the -y side: x to the right,
z up. The base of the actuator sits at the centre of the left edge's column ``base_column`` and
the view spans ``2 * half_extent_m`` vertically, so a backbone of total length L curling in
either direction stays in view when ``half_extent_m >= L``. Each segment is drawn as a thick
band (``thickness_m``, the actuator's 15 mm section by default) in its own colour, by stamping a
precomputed disc of pixels along the backbone, a third of its radius apart: the cost grows with the
backbone length in pixels, not with the image area.
"""

import numpy as np
from numpy.typing import ArrayLike, NDArray

from softseq_ros.wire.contract import SEGMENT_RGB

BACKGROUND_RGB = (236, 240, 244)
MOUNT_RGB = (60, 60, 60)
DEFAULT_THICKNESS_M = 0.015


class SideViewRenderer:
    """
    Renders backbones into an RGB image of ``width`` x ``height`` pixels.

    ``half_extent_m`` is half the height of the view [m]; the pixel size is
    ``2 * half_extent_m / height``. The base is drawn at column ``width * base_fraction``,
    mid-height. The image buffer is reused between calls (copy it if you keep it).
    """

    def __init__(self, width: int, height: int, half_extent_m: float,
                 thickness_m: float = DEFAULT_THICKNESS_M, base_fraction: float = 0.5) -> None:
        """Precompute the view transform, the pen and the background."""
        if int(width) < 1 or int(height) < 1:
            raise ValueError(f'image size must be at least 1 x 1 px, got {width} x {height}')
        if not half_extent_m > 0.0:
            raise ValueError(f'half_extent_m must be > 0, got {half_extent_m}')
        if not thickness_m > 0.0:
            raise ValueError(f'thickness_m must be > 0, got {thickness_m}')
        self.width, self.height = int(width), int(height)
        self.pixels_per_m = self.height / (2.0 * half_extent_m)
        self.base_px = (self.width * float(base_fraction), self.height / 2.0)
        radius = max(0.5, 0.5 * thickness_m * self.pixels_per_m)
        reach = int(np.ceil(radius))
        dy, dx = np.mgrid[-reach:reach + 1, -reach:reach + 1]
        inside = dx * dx + dy * dy <= radius * radius
        self._pen = np.stack([dy[inside], dx[inside]], axis=1)   # (K, 2) row, column offsets
        self._spacing = max(0.5, radius / 3.0)
        self._background = np.empty((self.height, self.width, 3), dtype=np.uint8)
        self._background[:] = BACKGROUND_RGB
        # The clamp the actuator hangs from: a dark block behind the base.
        row, column = int(round(self.base_px[1])), int(round(self.base_px[0]))
        half = reach + 2
        self._background[max(0, row - 2 * half):row + 2 * half,
                         max(0, column - 2 * half):max(0, column)] = MOUNT_RGB
        self.image = np.empty_like(self._background)

    def to_pixels(self, points: ArrayLike) -> NDArray[np.float64]:
        """Map (x, z) [m] to (column, row) pixel coordinates (row 0 at the top)."""
        xz = np.asarray(points, dtype=float)
        columns = self.base_px[0] + xz[..., 0] * self.pixels_per_m
        rows = self.base_px[1] - xz[..., 1] * self.pixels_per_m
        return np.stack([columns, rows], axis=-1)

    def render(self, points: ArrayLike, segment_ends: ArrayLike) -> NDArray[np.uint8]:
        """
        Draw one backbone and return the (height, width, 3) uint8 image.

        ``points`` (M, 2) are (x, z) [m] from the base; ``segment_ends`` (N,) is the index of
        each segment's last point.
        """
        pixels = self.to_pixels(points)
        ends = np.asarray(segment_ends, dtype=int)
        image = self.image
        image[:] = self._background
        start = 0
        for index, end in enumerate(ends):
            polyline = pixels[start:end + 1]
            colour = SEGMENT_RGB[index % len(SEGMENT_RGB)]
            self._stroke(image, polyline, colour)
            start = end
        return image

    def _stroke(self, image: NDArray[np.uint8], polyline: NDArray[np.float64],
                colour: tuple[int, int, int]) -> None:
        if polyline.shape[0] < 2:
            samples = polyline
        else:
            steps = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
            # Discs a third of their radius apart overlap enough to leave no visible scallops.
            counts = np.maximum(1, np.ceil(steps / self._spacing).astype(int))
            fractions = np.concatenate([np.arange(c) / c for c in counts])
            owners = np.repeat(np.arange(counts.size), counts)
            samples = polyline[owners] + fractions[:, None] * (polyline[owners + 1]
                                                               - polyline[owners])
            samples = np.vstack([samples, polyline[-1:]])
        centres = np.rint(samples[:, ::-1]).astype(int)               # (S, 2) row, column
        cells = (centres[:, None, :] + self._pen[None, :, :]).reshape(-1, 2)
        keep = ((cells[:, 0] >= 0) & (cells[:, 0] < self.height)
                & (cells[:, 1] >= 0) & (cells[:, 1] < self.width))
        cells = cells[keep]
        image[cells[:, 0], cells[:, 1]] = colour


def render_side_view(points: ArrayLike, segment_ends: ArrayLike, width: int, height: int,
                     half_extent_m: float,
                     thickness_m: float = DEFAULT_THICKNESS_M) -> NDArray[np.uint8]:
    """One-off side view (see SideViewRenderer); returns a new (height, width, 3) uint8 image."""
    renderer = SideViewRenderer(width, height, half_extent_m, thickness_m)
    return renderer.render(points, segment_ends).copy()
