"""The documentation's pictures are there (screenshots of the first view and of
an outlier with its error vector; the README shows one picture): every image the README
or a docs page links is a readable PNG in the repository."""

import re
from pathlib import Path

import PIL.Image
import pytest

ROOT = Path(__file__).resolve().parents[2]
IMAGE = re.compile(r"!\[[^\]]*\]\(([^)\s]+)\)")
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
# (page, the link as written, the file it names): a link is relative to its page's folder
LINKS = [
    (page, link, (page.parent / link).resolve())
    for page in PAGES
    for link in IMAGE.findall(page.read_text(encoding="utf-8"))
    if "://" not in link
]


def test_the_readme_shows_one_picture():
    shown = IMAGE.findall((ROOT / "README.md").read_text(encoding="utf-8"))
    assert len(shown) == 1, shown  # one picture, on the README's one screen
    assert shown[0].startswith("docs/img/"), shown


def test_the_viewer_screenshots_are_linked():
    tour = (ROOT / "docs" / "tour_viewer.md").read_text(encoding="utf-8")
    for name in ("img/viewer_first_view.png", "img/viewer_outlier_error.png", "img/viewer_legend.png"):
        assert name in IMAGE.findall(tour), f"docs/tour_viewer.md does not show {name}"


@pytest.mark.parametrize("page,link,path", LINKS, ids=[f"{p.relative_to(ROOT)}:{link}" for p, link, _ in LINKS])
def test_every_docs_image_is_a_png_in_the_repository(page, link, path):
    assert path.is_file(), f"{page.relative_to(ROOT)} links {link!r}, which is not in the repository"
    with PIL.Image.open(path) as im:
        assert im.format == "PNG", (link, im.format)
        # a real screenshot or figure, not a placeholder or an icon: the smallest side is 640 px today
        assert min(im.size) >= 200, (link, im.size)


@pytest.mark.xdist_group("chromium")  # a browser in a subprocess: tests/conftest.py cannot see it
@pytest.mark.browser
def test_the_screenshot_tool_makes_both_views(tmp_path):
    """tools/make_viewer_screenshots.py, which makes the README's viewer pictures, still runs: four PNGs
    at 1100 x 700, the second a different view (the camera on packet 100's error vector), the third
    the limb scene with the line of sight meeting the Earth, the fourth the Legend folder opened."""
    import os
    import subprocess
    import sys

    import numpy as np

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "make_viewer_screenshots.py"), "--out", str(tmp_path / "img")],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr[-4000:]
    imgs = []
    for name in ("viewer_first_view.png", "viewer_outlier_error.png", "viewer_limb.png", "viewer_legend.png"):
        with PIL.Image.open(tmp_path / "img" / name) as im:
            assert im.format == "PNG" and im.size == (1100, 700), (name, im.format, im.size)
            imgs.append(np.asarray(im.convert("RGB"), float))
    assert sorted(p.name for p in (tmp_path / "img").iterdir()) == [
        "viewer_first_view.png",
        "viewer_legend.png",
        "viewer_limb.png",
        "viewer_outlier_error.png",
    ]  # no temp left
    # the 3D view (left of the panel) changed: the camera moved to the error
    assert np.abs(imgs[0][:, :680] - imgs[1][:, :680]).mean() > 10.0
    # the limb scene: the Earth in view, not filling it (its mesh's blue, as tests/viz/test_viz_limb_browser.py
    # counts it, in the 3D view below the browser's notice: the bounds of that test, 15-90 %)
    r, g, b = (imgs[2][160:, :680, k] for k in range(3))
    earth = float(((b > r + 50) & (b > g + 25) & (r < 110)).mean())
    assert 0.15 < earth < 0.9, earth


STAMPS = ROOT / "docs" / "img" / "palette_stamps.json"


def test_every_docs_picture_is_stamped_with_the_colours_it_shows():
    """Each picture of docs/img records the viewer's colour tables it shows (``geoloc_viz.palette``) and
    their digest when it was taken. A colour changed since makes its digest differ: the picture fails
    here, named with the tool that retakes it, until it is retaken (and its stamp set to the new digest)
    or listed as not yet retaken (digest null, the "stale" list below, which may only shrink)."""
    import json

    from geoloc_viz.palette import TABLES, tables_digest

    stamps = json.loads(STAMPS.read_text(encoding="utf-8"))
    pictures = sorted(p.name for p in (ROOT / "docs" / "img").glob("*.png"))
    assert sorted(stamps) == pictures, set(stamps) ^ set(pictures)
    changed = []
    for name, s in stamps.items():
        assert s["tables"] and set(s["tables"]) <= set(TABLES), (name, s["tables"])
        if s["digest"] is not None and s["digest"] != tables_digest(*s["tables"]):
            changed.append(
                f"{name}: the {', '.join(s['tables'])} colours changed since it was taken; retake it ({s['made_by']})"
            )
    assert not changed, "\n".join(changed)


# pictures taken before a colour change they show, not yet retaken: this list may only shrink
STALE: set[str] = set()


def test_the_stale_pictures_are_listed_and_the_list_only_shrinks():
    import json

    stamps = json.loads(STAMPS.read_text(encoding="utf-8"))
    stale = {name for name, s in stamps.items() if s["digest"] is None}
    assert stale <= STALE, f"newly unstamped pictures (retake them instead): {sorted(stale - STALE)}"
    assert stale == STALE, f"retaken: take them off STALE here: {sorted(STALE - stale)}"
