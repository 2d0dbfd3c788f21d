"""recon.halflit: which side of a tube that shows its highlight only is lit, told from the stretch at the base."""
import warnings

import numpy as np
import pytest

from recon.halflit import BASE_STRETCH, half_lit_moves, lit_side

BASE_PX, AXIS_PX, FULL_PX = np.array([40.0, 100.0]), np.array([1.0, 0.0]), 10.0


def _stretch(offset_px, width_px=3.0, bend_per_px=0.0):
    """Centres every 2 px from the base along the axis (+x), ``offset_px`` across it (+y is the normal (-d_y, d_x)
    of the tangent +x), bending away by ``bend_per_px`` * along**2; their tangents and widths."""
    along = 2.0 * np.arange(BASE_STRETCH)
    c = BASE_PX + np.c_[along, offset_px + bend_per_px * along ** 2]
    d = np.gradient(c, axis=0)
    return c, d / np.linalg.norm(d, axis=1, keepdims=True), np.full(BASE_STRETCH, width_px)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_narrow_stretch_off_the_axis_by_half_the_missing_width_tells_the_side_and_the_fraction(sign):
    c, d, w = _stretch(sign * 3.5)  # 3 px of a 10 px tube: 3.5 px off
    assert lit_side(BASE_PX, AXIS_PX, FULL_PX, c, d, w) == (sign, pytest.approx(0.3))


@pytest.mark.parametrize("case", ["on the axis", "full width", "bends away", "axis end on"])
def test_a_stretch_that_does_not_show_a_lit_side_tells_nothing(case):
    """A narrow stretch on the axis (a thinner tube), a full one off it, one that bends away from the axis
    (offset growing to 5 px over 46 px), and an axis seen end on (no line to run parallel to) tell nothing,
    and raise no warning."""
    c, d, w = {"on the axis": _stretch(0.0), "full width": _stretch(3.5, width_px=9.5),
               "bends away": _stretch(2.0, bend_per_px=0.0015), "axis end on": _stretch(3.5)}[case]
    axis = np.zeros(2) if case == "axis end on" else AXIS_PX
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert lit_side(BASE_PX, axis, FULL_PX, c, d, w) == (0.0, 1.0)


def test_narrow_cross_sections_move_by_half_the_width_they_miss_and_full_ones_stay():
    """Sections as narrow as the base stretch (0.3 of the tube) take the width that fraction gives and move by
    half the difference; a run of full ones among them stays where it is."""
    width = np.r_[np.full(60, 3.0), np.full(30, 10.0), np.full(60, 2.4)]
    narrow, full, move = half_lit_moves(width, 0.3, 7.0, 10.0)
    assert not narrow[60:90].any() and narrow[:60].all() and narrow[90:].all()
    np.testing.assert_allclose(full[:60], 10.0)
    np.testing.assert_allclose(move[:60], 3.5)
    np.testing.assert_allclose(full[60:], 8.0)  # 2.4 / 0.3: the thinner tube
    np.testing.assert_allclose(move[60:], 2.8)
