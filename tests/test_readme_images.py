"""The README's pictures are there (issue 34's Done-when: screenshots of the first view and of an
outlier with its error vector): every image the README links is a readable PNG in the repository."""

import re
from pathlib import Path

import PIL.Image
import pytest

ROOT = Path(__file__).resolve().parents[1]
LINKS = re.findall(r"!\[[^\]]*\]\(([^)\s]+)\)", (ROOT / "README.md").read_text(encoding="utf-8"))


def test_the_issue_34_screenshots_are_linked():
    for name in ("docs/img/viewer_first_view.png", "docs/img/viewer_outlier_error.png"):
        assert name in LINKS, f"README.md does not show {name}"


@pytest.mark.parametrize("link", LINKS)
def test_every_readme_image_is_a_png_in_the_repository(link):
    path = ROOT / link
    assert path.is_file(), f"README.md links {link!r}, which is not in the repository"
    with PIL.Image.open(path) as im:
        assert im.format == "PNG", (link, im.format)
        # a real screenshot, not a placeholder or an icon: the README's smallest side is 640 px today
        assert min(im.size) >= 200, (link, im.size)
