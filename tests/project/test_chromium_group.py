"""tests/conftest.py's Chromium group: every test that opens headless Chromium, and only those.

``tools/test.sh`` runs two pytest-xdist workers; the tests that open a browser share one of
them (xdist group "chromium"), found per test by ``conftest._opens_chromium``. A test the
look-up misses must fail rather than run a second browser beside the first: ``chromium()``
refuses to launch outside the group. None of these tests opens a browser.
"""

import os

import pytest

import conftest


def test_the_group_holds_the_browser_tests_and_not_their_neighbours():
    import test_viz_labels
    import test_viz_picture
    import test_viz_uncertainty

    # the labels tests open Chromium through the module's helper _check
    assert conftest._opens_chromium(test_viz_labels.test_limb_labels_do_not_overlap, set())
    assert conftest._opens_chromium(test_viz_uncertainty.test_a_person_hides_the_ellipse_in_chromium, set())
    assert conftest._opens_chromium(test_viz_picture.test_click_a_pixel_in_the_panel_and_the_terrain_in_chromium, set())
    # the same modules' CPU-only tests run on either worker
    assert not conftest._opens_chromium(
        test_viz_uncertainty.test_the_ellipse_in_the_scene_is_the_predicted_90_percent_ellipse, set()
    )
    assert not conftest._opens_chromium(test_viz_picture.test_pixel_pick_equals_geoloc_locate, set())


def test_a_browser_test_outside_the_group_fails_loudly(tmp_path):
    # this test is outside the group (it names the launcher only as a string, which the look-up
    # does not follow): the launcher must refuse before it starts anything
    import test_viz_browser

    assert os.environ.get(conftest.CHROMIUM_GROUP_ENV) == "0"
    launcher = getattr(test_viz_browser, "chrom" + "ium")
    with pytest.raises(AssertionError, match="outside the xdist group 'chromium'"):
        with launcher(tmp_path):
            pass
