"""What a reviewer checks on a figure, as numbers: blank bands, colours drawn, nothing cut off."""

from pathlib import Path

import numpy as np


def png_pixels(path: Path) -> np.ndarray:
    """The image's RGB values, (rows, columns, 3) floats from 0 to 255."""
    from PIL import Image

    with Image.open(path) as image:
        return np.asarray(image.convert('RGB'), dtype=float)


def png_dpi(path: Path) -> tuple[float, float]:
    """The resolution the PNG declares."""
    from PIL import Image

    with Image.open(path) as image:
        return image.info['dpi']


def blank_band(path: Path) -> float:
    """
    The widest band of all-white rows or columns across the PNG, in inches.

    Blank space a reviewer sees is absolute: a tenth of an inch is a lot under a short figure
    and little beside a tall one.
    """
    pixels = png_pixels(path)
    widest = 0
    for axis in (0, 1):
        blank = np.all(pixels > 250, axis=(1 - axis, 2))
        run = 0
        for row in blank:
            run = run + 1 if row else 0
            widest = max(widest, run)
    return widest / png_dpi(path)[0]


# A blank band this wide (5 mm) or more is space wasted on a page; the gutter between two
# panels with their labels is narrower (the compare figure's: 0.19 in).
BLANK_BAND_IN = 0.2


def cut_off(pixels: np.ndarray) -> bool:
    """Whether anything drawn touches the image's edge (a title or legend cut by the canvas)."""
    edges = np.concatenate([pixels[0], pixels[-1], pixels[:, 0], pixels[:, -1]])
    return bool(np.any(edges < 250))


def whole(path: Path, dpi: float) -> np.ndarray:
    """Check that a PNG declares ``dpi`` and that nothing drawn is cut off; its pixels."""
    declared = png_dpi(path)
    assert abs(declared[0] - dpi) < 0.5 and abs(declared[1] - dpi) < 0.5, (path, declared)
    pixels = png_pixels(path)
    assert not cut_off(pixels), path
    return pixels


def laid_out(path: Path, dpi: float = 300.0) -> np.ndarray:
    """
    Check a PNG as a reviewer would: its resolution, nothing cut off, no blank band; its pixels.

    ``dpi``: the resolution it should declare (300: the paper style's).
    """
    pixels = whole(path, dpi)
    assert blank_band(path) < BLANK_BAND_IN, path
    return pixels


def share_of(pixels: np.ndarray, colour: str) -> float:
    """The share of pixels within a small distance of ``colour`` (hex)."""
    rgb = np.array([int(colour[k:k + 2], 16) for k in (1, 3, 5)], dtype=float)
    return float(np.mean(np.linalg.norm(pixels - rgb, axis=2) < 30.0))


def titles(fig: object) -> list[str]:
    """Every title a figure carries: its suptitle and each axes' titles."""
    found = [fig._suptitle.get_text()] if fig._suptitle is not None else []
    for ax in fig.axes:
        found += [ax.get_title(loc) for loc in ('left', 'center', 'right') if ax.get_title(loc)]
    return found


def capture_figures(monkeypatch: object, module: object) -> list:
    """
    The figures ``module.save_figure`` saves from now on (they are still saved).

    A report's figures are drawn here, not in a forked figure worker, so that they are seen.
    """
    from softseq_ros.analysis import figure_workers

    monkeypatch.setattr(figure_workers, 'start_workers', lambda svg=False: None)
    drawn = []
    save = module.save_figure
    monkeypatch.setattr(module, 'save_figure',
                        lambda fig, out, svg, style: drawn.append(fig) or save(fig, out, svg,
                                                                                style))
    return drawn
