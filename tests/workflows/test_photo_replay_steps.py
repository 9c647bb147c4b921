"""The named steps of the photo replay (geoloc.workflows.photo_replay.replay_photos), each alone."""

from __future__ import annotations

from geoloc.workflows.photo_replay import _targets_by_photo


def _target(line, image, truth_h_m=None):
    return {"line": line, "image": image, "row": 1.0, "col": 1.0, "truth_h_m": truth_h_m}


def test_targets_are_grouped_by_photo_and_the_unusable_ones_said():
    targets = [
        _target(2, "DJI_0001.JPG", 300.0),
        _target(3, "dji_0002", 300.0),  # named without its extension, in lower case
        _target(4, "DJI_0003.JPG", 300.0),  # a photo that could not be read
        _target(5, "DJI_0003", 300.0),
        _target(6, "DJI_0009.JPG", 300.0),  # a photo not given
        _target(7, "DJI_0001.JPG"),  # no height and no DEM
        _target(8, "DJI_0001.JPG", 310.0),
    ]
    photos = {"DJI_0001.JPG": {}, "DJI_0002.JPG": {}}
    bad = {"DJI_0003.JPG": "no GPS"}
    messages: list[str] = []
    by_photo, order = _targets_by_photo(targets, photos, bad, False, messages)
    assert by_photo == {"DJI_0001.JPG": [0, 6], "DJI_0002.JPG": [1]}
    assert order == [0, 1, 6]
    assert messages == [
        "targets file line 6: image 'DJI_0009.JPG' is not among the photos given "
        "(DJI_0001.JPG, DJI_0002.JPG, DJI_0003.JPG): skipped",
        "targets file line 7 (DJI_0001.JPG): no DEM and no truth_h_m: no height to locate the target at; skipped",
        "DJI_0003.JPG: 2 target(s) skipped (the photo could not be used)",
    ]
    # on a surface a target needs no height of its own
    by_photo, order = _targets_by_photo(targets, photos, bad, True, [])
    assert order == [0, 1, 5, 6]
