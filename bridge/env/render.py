"""Pictures and text for Gymnasium's ``render()``, without pygame.

``draw_cartpole`` rasterises a cart-pole scene with plain numpy (rectangles, thick lines and
discs as masks on their bounding boxes), fast enough to call every step. ``plot_signals``
draws time series with matplotlib's Agg canvas, never touching pyplot's global state, and
``ansi_line`` is the one-line text frame of render mode ``"ansi"``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import numpy.typing as npt

from bridge.errors import BridgeError, ConfigError, DependencyMissing

Image = npt.NDArray[np.uint8]
RGB = tuple[int, int, int]

BACKGROUND_RGB: RGB = (255, 255, 255)
TRACK_RGB: RGB = (0, 0, 0)
CART_RGB: RGB = (38, 50, 72)
POLE_RGB: RGB = (204, 153, 102)
AXLE_RGB: RGB = (128, 128, 204)
MIN_SIZE_PX = 32


@dataclass(frozen=True)
class _Layout:
    """Pixel geometry of one (size, x_limit, pole length) combination."""

    scale_px_per_m: float
    centre_x: float
    track_y: int
    cart_w: float
    cart_h: float
    pole_px: float
    pole_radius: float
    axle_radius: float


@lru_cache(maxsize=16)
def _layout(width: int, height: int, x_limit: float, pole_length_m: float) -> _Layout:
    cart_w = max(8.0, width / 12.0)
    cart_h = 0.6 * cart_w
    margin = cart_w / 2.0 + 0.02 * width
    track_y = round(0.75 * height)
    # [-x_limit, x_limit] spans the width less a margin, unless the upright pole would not fit.
    scale = (width - 2.0 * margin) / (2.0 * x_limit)
    headroom = track_y - cart_h - 0.03 * height
    scale = min(scale, headroom / pole_length_m)
    pole_radius = max(1.0, cart_w / 10.0)
    return _Layout(
        scale_px_per_m=scale,
        centre_x=width / 2.0,
        track_y=track_y,
        cart_w=cart_w,
        cart_h=cart_h,
        pole_px=pole_length_m * scale,
        pole_radius=pole_radius,
        axle_radius=1.3 * pole_radius,
    )


def draw_cartpole(
    x: float,
    theta: float,
    *,
    x_limit: float = 2.4,
    pole_length_m: float = 1.0,
    width: int = 600,
    height: int = 400,
) -> Image:
    """An RGB picture of a cart-pole, as Gymnasium's ``render_mode="rgb_array"`` returns.

    Args:
        x: cart position in metres; 0 is the centre of the picture.
        theta: pole angle from vertical in radians; positive tilts the pole towards +x.
        x_limit: the track half-length in metres that the picture must show.
        pole_length_m: full pole length in metres.
        width: picture width in pixels.
        height: picture height in pixels.

    Returns:
        A uint8 array of shape ``(height, width, 3)``.
    """
    _check_cartpole(x, theta, x_limit, pole_length_m, width=width, height=height)
    geometry = _layout(width, height, float(x_limit), float(pole_length_m))
    image: Image = _background(width, height, geometry.track_y).copy()
    track = geometry.track_y
    # Far-off positions are clamped so pixel arithmetic stays small; the cart is then off-picture.
    cart_x = min(max(geometry.centre_x + x * geometry.scale_px_per_m, -2.0 * width), 3.0 * width)
    top = track - geometry.cart_h
    half = geometry.cart_w / 2.0
    _fill_rect(image, (cart_x - half, cart_x + half), (round(top), track), CART_RGB)
    tip = (cart_x + geometry.pole_px * math.sin(theta), top - geometry.pole_px * math.cos(theta))
    _capsule(image, (cart_x, top), tip, geometry.pole_radius, POLE_RGB)
    _capsule(image, (cart_x, top), (cart_x, top), geometry.axle_radius, AXLE_RGB)
    return image


def _check_cartpole(
    x: float, theta: float, x_limit: float, pole_length_m: float, *, width: int, height: int
) -> None:
    if not (math.isfinite(x) and math.isfinite(theta)):
        raise BridgeError(
            f"draw_cartpole: x={x!r} and theta={theta!r} must both be finite; the simulation has "
            "probably diverged, check the last step's state"
        )
    if not (x_limit > 0 and pole_length_m > 0 and math.isfinite(x_limit) and math.isfinite(pole_length_m)):
        raise ConfigError(
            f"draw_cartpole: x_limit={x_limit!r} and pole_length_m={pole_length_m!r} must be "
            "positive, finite lengths in metres"
        )
    if width < MIN_SIZE_PX or height < MIN_SIZE_PX:
        raise ConfigError(
            f"draw_cartpole: the picture must be at least {MIN_SIZE_PX}x{MIN_SIZE_PX} pixels, "
            f"got width={width}, height={height}"
        )


@lru_cache(maxsize=4)
def _background(width: int, height: int, track_y: int) -> Image:
    """The empty scene with its track, copied for each picture (a copy is cheaper than a fill)."""
    image = np.empty((height, width, 3), dtype=np.uint8)
    image[...] = BACKGROUND_RGB
    _fill_rect(image, (0.0, float(width)), (track_y, track_y + max(1, height // 200)), TRACK_RGB)
    image.flags.writeable = False
    return image


def _fill_rect(image: Image, cols: tuple[float, float], rows: tuple[int, int], rgb: RGB) -> None:
    height, width = image.shape[:2]
    col0, col1 = max(0, round(cols[0])), min(width, round(cols[1]))
    row0, row1 = max(0, rows[0]), min(height, rows[1])
    if col0 < col1 and row0 < row1:
        image[row0:row1, col0:col1] = rgb


def _capsule(image: Image, a: tuple[float, float], b: tuple[float, float], radius: float, rgb: RGB) -> None:
    """Paint every pixel within ``radius`` of segment a-b (a disc when a == b).

    Only the segment's bounding box is examined, so the cost follows the shape, not the image.
    """
    height, width = image.shape[:2]
    col0 = max(0, math.floor(min(a[0], b[0]) - radius))
    col1 = min(width, math.ceil(max(a[0], b[0]) + radius) + 1)
    row0 = max(0, math.floor(min(a[1], b[1]) - radius))
    row1 = min(height, math.ceil(max(a[1], b[1]) + radius) + 1)
    if col0 >= col1 or row0 >= row1:
        return
    cols = np.arange(col0, col1, dtype=np.float64)[np.newaxis, :] - a[0]
    rows = np.arange(row0, row1, dtype=np.float64)[:, np.newaxis] - a[1]
    dx, dy = b[0] - a[0], b[1] - a[1]
    length2 = dx * dx + dy * dy
    if length2 > 0.0:
        # Position of the closest point on the segment, as a fraction of its length.
        t = cols * dx + rows * dy
        t *= 1.0 / length2
        np.clip(t, 0.0, 1.0, out=t)
        off_x, off_y = cols - t * dx, rows - t * dy
    else:
        off_x, off_y = np.broadcast_arrays(cols, rows)
    mask = off_x * off_x + off_y * off_y <= radius * radius
    image[row0:row1, col0:col1][mask] = rgb


def plot_signals(
    times: npt.NDArray[np.float64],
    series: Mapping[str, npt.NDArray[np.float64]],
    *,
    title: str = "",
    width: int = 640,
    height: int = 480,
) -> Image:
    """Plot named signals against time on one set of axes with a legend.

    Args:
        times: sample times in seconds, shape ``(n,)``.
        series: signal name to values, each of shape ``(n,)``.
        title: title above the axes.
        width: picture width in pixels.
        height: picture height in pixels.

    Returns:
        A uint8 RGB array of shape ``(height, width, 3)``.

    Raises:
        DependencyMissing: matplotlib is not installed.
        ConfigError: the arrays do not have matching one-dimensional shapes.
    """
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise DependencyMissing(
            "matplotlib", "plotting signals in render()", "pip install 'fmu-bridge[viz]'"
        ) from exc
    t = _check_signals(times, series, width, height)
    dpi = 100.0
    figure = Figure(figsize=(width / dpi, height / dpi), dpi=dpi, layout="constrained")
    canvas = FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    for name, values in series.items():
        axes.plot(t, np.asarray(values, dtype=np.float64), label=name, linewidth=1.5)
    axes.set_xlabel("time [s]")
    axes.grid(True, alpha=0.3)
    if title:
        axes.set_title(title)
    if series:
        axes.legend(loc="best", fontsize="small")
    canvas.draw()  # type: ignore[no-untyped-call]
    rgb = np.asarray(canvas.buffer_rgba())[:, :, :3]  # type: ignore[no-untyped-call]
    return _fit(rgb, width, height)


def _check_signals(
    times: npt.NDArray[np.float64],
    series: Mapping[str, npt.NDArray[np.float64]],
    width: int,
    height: int,
) -> npt.NDArray[np.float64]:
    t = np.asarray(times, dtype=np.float64)
    if t.ndim != 1:
        raise ConfigError(f"plot_signals: times must be one-dimensional, got shape {t.shape}")
    for name, values in series.items():
        shape = np.shape(values)
        if shape != t.shape:
            raise ConfigError(
                f"plot_signals: series {name!r} has shape {shape} but times has shape {t.shape}; "
                "pass one value per sample time"
            )
    if width < MIN_SIZE_PX or height < MIN_SIZE_PX:
        raise ConfigError(
            f"plot_signals: the picture must be at least {MIN_SIZE_PX}x{MIN_SIZE_PX} pixels, "
            f"got width={width}, height={height}"
        )
    return t


def _fit(rgb: npt.NDArray[np.uint8], width: int, height: int) -> Image:
    """Exactly ``(height, width, 3)``: matplotlib may round a figure size by a pixel."""
    out = np.empty((height, width, 3), dtype=np.uint8)
    out[...] = BACKGROUND_RGB
    rows, cols = min(height, rgb.shape[0]), min(width, rgb.shape[1])
    out[:rows, :cols] = rgb[:rows, :cols]
    return out


def ansi_line(time_s: float, step: int, names: Sequence[str], values: npt.NDArray[np.float64]) -> str:
    """One line of text for render mode ``"ansi"``: time, step index and each named value.

    Example: ``t=1.250s step=25 | x=+0.01234 theta=-0.04561``.
    """
    if len(names) != len(values):
        raise ConfigError(f"ansi_line: {len(names)} names but {len(values)} values; pass one value per name")
    cells = " ".join(
        f"{name}={value:+.4g}" for name, value in zip(names, np.asarray(values).tolist(), strict=True)
    )
    return f"t={time_s:.3f}s step={step} | {cells}"
