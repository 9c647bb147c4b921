"""The README and the documentation site: a README of one screen that starts with the two
commands, and a site that builds with `mkdocs build --strict` (the command `tools/docs.sh` runs),
with an API reference that lists every public module of the core and of the viewer."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text(encoding="utf-8")
API = ROOT / "docs" / "api"
# a screen: GitHub's rendered README on a 1080p display shows about 40 source lines of this one
# (prose wrapped at about 95 characters); the two commands must sit above that line
FIRST_SCREEN_LINES = 40


def test_the_readme_is_at_most_10_kb():
    assert len(README.encode("utf-8")) <= 10_000, len(README.encode("utf-8"))


def test_the_readmes_first_screen_holds_the_two_commands_first():
    head = README.splitlines()[:FIRST_SCREEN_LINES]
    blocks = re.findall(r"```bash\n(.*?)```", "\n".join(head) + "\n", re.S)
    # the first two code blocks are the two commands, exactly as tools/run.sh and tools/test.sh say
    assert [b.strip() for b in blocks[:2]] == ["bash tools/run.sh", "bash tools/test.sh"], blocks


def test_the_readme_names_the_one_docs_command():
    blocks = [b.strip() for b in re.findall(r"```bash\n(.*?)```", README, re.S)]
    assert "bash tools/docs.sh" in blocks, blocks
    assert (ROOT / "tools" / "docs.sh").is_file()


def _section(text: str, heading: str) -> str:
    start = text.index(heading)
    end = text.find("\n#", start + len(heading))
    return text[start + len(heading) : end if end >= 0 else len(text)].strip()


def test_the_install_paragraph_is_the_same_in_the_readme_and_the_docs():
    # the README keeps it (the lead's paragraph); docs/install.md holds it for the site, with the
    # links relative to docs/ instead of the repository root, and assets/README.md (outside the
    # site) named rather than linked
    readme = _section(README, "### Installing the package elsewhere")
    docs = _section((ROOT / "docs" / "install.md").read_text(encoding="utf-8"), "## Installing the package elsewhere")
    as_on_the_site = readme.replace("](docs/", "](").replace(
        "[assets/README.md](assets/README.md)", "`assets/README.md`"
    )
    assert as_on_the_site == docs


def _public_modules() -> set[str]:
    """Every module of geoloc and geoloc_viz whose dotted name has no part starting with an
    underscore, the command-line packages excepted (`geoloc VERB --help` and the tour pages)."""
    found = set()
    for pkg_dir in (ROOT / "geoloc", ROOT / "viz" / "geoloc_viz"):
        for p in pkg_dir.rglob("*.py"):
            parts = list(p.relative_to(pkg_dir.parent).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            if any(x.startswith("_") for x in parts) or "cli" in parts[1:2]:
                continue
            found.add(".".join(parts))
    return found


def _documented() -> dict[str, str]:
    out = {}
    for page in sorted(API.glob("*.md")):
        for name in re.findall(r"^::: ([\w.]+)\s*$", page.read_text(encoding="utf-8"), re.M):
            assert name not in out, f"{name} is on {out.get(name)} and {page.name}"
            out[name] = page.name
    return out


def test_the_api_reference_lists_every_public_module():
    public, documented = _public_modules(), _documented()
    assert "geoloc.locate" in public and "geoloc_viz.app" in public  # the walk sees both packages
    missing = sorted(public - set(documented))
    assert not missing, f"public modules missing from docs/api/*.md (add a '::: name' line): {missing}"
    stale = sorted(set(documented) - public)
    assert not stale, f"docs/api/*.md names modules that are not there (or not public): {stale}"


def _words(html: str) -> str:
    """A page's text as a reader sees it: tags out (the highlighter splits code into spans)."""
    import html as html_mod

    return " ".join(html_mod.unescape(re.sub(r"<[^>]+>", " ", html)).split())


def test_the_site_builds_strict_from_the_sources(tmp_path):
    site = tmp_path / "site"
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    r = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "mkdocs.yml"), "-d", str(site)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    log = r.stdout + r.stderr
    assert r.returncode == 0, log[-4000:]
    assert "WARNING" not in log, log[-4000:]
    for page in ("index.html", "install.html", "tour_cli.html", "architecture.html", "api/index.html"):
        assert (site / page).is_file(), page
    index = (site / "index.html").read_text(encoding="utf-8")
    assert "bash tools/run.sh" in _words((site / "install.html").read_text(encoding="utf-8"))
    assert 'href="api/index.html"' in index
    # the API reference is generated from the docstrings: locate's own docstring text is there
    locate = (site / "api" / "locate.html").read_text(encoding="utf-8")
    assert 'id="geoloc.locate.locate"' in locate, "no geoloc.locate.locate heading in the API page"
    from geoloc.locate import locate as locate_fn

    first_words = " ".join(locate_fn.__doc__.split()[:4])
    assert first_words in _words(locate), first_words
    # the viewer's page: its package is read from viz/ without importing viser
    assert 'id="geoloc_viz.app"' in (site / "api" / "viz.html").read_text(encoding="utf-8")
    # the search index covers the API pages too
    assert "geoloc.locate.locate" in (site / "search" / "search_index.json").read_text(encoding="utf-8")
