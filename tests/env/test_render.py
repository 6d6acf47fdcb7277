"""Rendering: the cart-pole picture shows the state it is given; plots and text lines are usable."""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest

from bridge.env.render import (
    AXLE_RGB,
    CART_RGB,
    POLE_RGB,
    ansi_line,
    draw_cartpole,
    plot_signals,
)
from bridge.errors import BridgeError, ConfigError, DependencyMissing


def pixels_of(image: np.ndarray, rgb: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of every pixel painted exactly ``rgb``."""
    rows, cols = np.nonzero(np.all(image == np.array(rgb, dtype=np.uint8), axis=-1))
    return rows, cols


def cart_box(image: np.ndarray) -> tuple[float, int, int]:
    """Centre column, top row and pixel count of the cart, decoded from its colour."""
    rows, cols = pixels_of(image, CART_RGB)
    assert rows.size > 0, "no cart pixels"
    return (cols.min() + cols.max()) / 2.0, int(rows.min()), int(rows.size)


def test_picture_has_requested_shape_and_dtype() -> None:
    for width, height in [(600, 400), (320, 240), (97, 61)]:
        image = draw_cartpole(0.1, 0.2, width=width, height=height)
        assert image.shape == (height, width, 3)
        assert image.dtype == np.uint8
        assert image.flags.writeable


def test_background_is_white_and_all_parts_are_drawn() -> None:
    image = draw_cartpole(0.0, 0.3)
    assert tuple(image[5, 5]) == (255, 255, 255)
    for rgb in (CART_RGB, POLE_RGB, AXLE_RGB):
        assert pixels_of(image, rgb)[0].size > 20


def test_picture_changes_with_x_and_theta() -> None:
    base = draw_cartpole(0.0, 0.0)
    assert not np.array_equal(base, draw_cartpole(0.3, 0.0))
    assert not np.array_equal(base, draw_cartpole(0.0, 0.1))
    assert np.array_equal(base, draw_cartpole(0.0, 0.0))


def test_cart_moves_linearly_with_x_and_stays_visible_at_the_limits() -> None:
    centres = [cart_box(draw_cartpole(x, 0.0))[0] for x in (-1.0, 0.0, 1.0)]
    assert centres[1] == pytest.approx(300.0, abs=1.0)
    assert centres[2] - centres[1] == pytest.approx(centres[1] - centres[0], abs=1.0)
    assert centres[2] > centres[1] + 50
    _, _, full_area = cart_box(draw_cartpole(0.0, 0.0))
    for x in (-2.4, 2.4):
        centre, _, area = cart_box(draw_cartpole(x, 0.0, x_limit=2.4))
        assert area == full_area, "the cart at the track limit is cut off"
        assert abs(centre - 300.0) > 0.8 * 300.0, "the track does not span most of the width"


@pytest.mark.parametrize("theta", [0.5, -0.5])
def test_pole_lies_on_the_side_theta_says(theta: float) -> None:
    image = draw_cartpole(0.2, theta)
    centre, top, _ = cart_box(image)
    rows, cols = pixels_of(image, POLE_RGB)
    # Well above the pivot, the thick pole's width no longer reaches across the centre line.
    above = rows < top - 30
    right = np.count_nonzero(above & (cols > centre))
    left = np.count_nonzero(above & (cols < centre))
    if theta > 0:
        assert right > 100
        assert left == 0
    else:
        assert left > 100
        assert right == 0


@pytest.mark.parametrize("theta", [0.0, 0.3, -0.7, 1.2])
def test_pole_direction_matches_theta(theta: float) -> None:
    image = draw_cartpole(0.0, theta)
    rows, cols = pixels_of(image, POLE_RGB)
    # Principal axis of the pole pixels, as an angle from vertical (image rows grow downwards).
    points = np.stack([cols - cols.mean(), rows.mean() - rows])
    eigenvalues, eigenvectors = np.linalg.eigh(np.cov(points))
    dx, dy = eigenvectors[:, np.argmax(eigenvalues)]
    if dy < 0:
        dx, dy = -dx, -dy
    assert math.atan2(dx, dy) == pytest.approx(theta, abs=0.03)


def test_upright_pole_is_symmetric_about_the_cart() -> None:
    image = draw_cartpole(0.0, 0.0)
    centre, _, _ = cart_box(image)
    _, cols = pixels_of(image, POLE_RGB)
    assert cols.mean() == pytest.approx(centre, abs=0.5)


def test_hanging_pole_is_drawn_below_the_pivot() -> None:
    image = draw_cartpole(0.0, math.pi)
    _, top, _ = cart_box(image)
    rows, _ = pixels_of(image, POLE_RGB)
    assert rows.size > 100
    assert rows.min() >= top - 10


def test_longer_pole_has_more_pixels() -> None:
    short = pixels_of(draw_cartpole(0.0, 0.2, pole_length_m=0.5), POLE_RGB)[0].size
    long = pixels_of(draw_cartpole(0.0, 0.2, pole_length_m=1.0), POLE_RGB)[0].size
    assert long > 1.6 * short


def test_cart_far_off_the_track_is_simply_not_visible() -> None:
    image = draw_cartpole(1e9, 0.0)
    assert pixels_of(image, CART_RGB)[0].size == 0


def test_non_finite_state_is_an_error() -> None:
    with pytest.raises(BridgeError, match="must both be finite"):
        draw_cartpole(float("nan"), 0.0)


@pytest.mark.parametrize("kwargs", [{"width": 10}, {"height": 0}, {"x_limit": 0.0}, {"pole_length_m": -1.0}])
def test_bad_picture_arguments_are_config_errors(kwargs: dict[str, float]) -> None:
    with pytest.raises(ConfigError, match="draw_cartpole"):
        draw_cartpole(0.0, 0.0, **kwargs)  # type: ignore[arg-type]


def cycle_colours(count: int) -> list[np.ndarray]:
    from matplotlib import colors, rcParams

    cycle = rcParams["axes.prop_cycle"].by_key()["color"]
    return [np.round(np.array(colors.to_rgb(c)) * 255).astype(np.uint8) for c in cycle[:count]]


def test_plot_is_a_non_blank_picture_with_the_line_colours() -> None:
    pytest.importorskip("matplotlib")
    times = np.linspace(0.0, 10.0, 500)
    image = plot_signals(times, {"x": np.sin(times), "theta": np.cos(times)}, title="episode 3")
    assert image.shape == (480, 640, 3)
    assert image.dtype == np.uint8
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 50
    for rgb in cycle_colours(2):
        assert pixels_of(image, tuple(int(v) for v in rgb))[0].size > 100


def test_plot_with_one_signal_has_only_the_first_line_colour() -> None:
    pytest.importorskip("matplotlib")
    times = np.linspace(0.0, 1.0, 50)
    image = plot_signals(times, {"x": times**2}, width=320, height=240)
    assert image.shape == (240, 320, 3)
    first, second = cycle_colours(2)
    assert pixels_of(image, tuple(int(v) for v in first))[0].size > 50
    assert pixels_of(image, tuple(int(v) for v in second))[0].size == 0


@pytest.mark.parametrize(("width", "height"), [(333, 217), (601, 401)])
def test_plot_size_is_exact_for_any_pixel_size(width: int, height: int) -> None:
    pytest.importorskip("matplotlib")
    times = np.arange(10.0)
    assert plot_signals(times, {"x": times}, width=width, height=height).shape == (height, width, 3)


def test_plot_leaves_pyplot_alone() -> None:
    pytest.importorskip("matplotlib")
    imported_before = "matplotlib.pyplot" in sys.modules
    plot_signals(np.arange(3.0), {"x": np.arange(3.0)})
    if not imported_before:
        assert "matplotlib.pyplot" not in sys.modules


def test_plot_rejects_series_of_the_wrong_length() -> None:
    pytest.importorskip("matplotlib")
    with pytest.raises(ConfigError, match="series 'theta' has shape \\(4,\\) but times has shape \\(5,\\)"):
        plot_signals(np.arange(5.0), {"x": np.arange(5.0), "theta": np.arange(4.0)})


def test_plot_without_matplotlib_says_how_to_install_it(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    with pytest.raises(DependencyMissing) as info:
        plot_signals(np.arange(3.0), {"x": np.arange(3.0)})
    assert info.value.package == "matplotlib"
    assert "pip install 'fmu-bridge[viz]'" in str(info.value)


def test_ansi_line_shows_time_step_and_values() -> None:
    line = ansi_line(1.25, 25, ["x", "theta"], np.array([0.012345, -0.0456]))
    assert line == "t=1.250s step=25 | x=+0.01235 theta=-0.0456"
    assert "\n" not in line


def test_ansi_line_rejects_mismatched_names_and_values() -> None:
    with pytest.raises(ConfigError, match="2 names but 1 values"):
        ansi_line(0.0, 0, ["x", "theta"], np.array([1.0]))
