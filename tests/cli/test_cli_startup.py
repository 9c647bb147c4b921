"""The command line answers at once: ``geoloc --help`` imports no verb, ``geoloc VERB`` only its own,
and a one-pixel ``geoloc locate`` no numba, scipy, pyproj or rasterio.

Each verb's one-line help lives in :data:`geoloc.cli.VERB_HELP`, which its ``register`` reads;
the help lists the verbs from it with their modules unimported. What a command imports is read
in a new interpreter (``sys.modules`` after ``main``), not timed: the time is
``benchmarks/bench_startup.py``'s.
"""

import subprocess
import sys

from geoloc.cli import VERB_HELP, VIEWER_VERBS, build_parser

#: Libraries a verb's work needs and a help text does not.
HEAVY = ("numba", "scipy", "pyproj", "rasterio", "matplotlib", "viser", "rerun")


def _imported_after(argv) -> list:
    code = (
        "import sys\nfrom geoloc.cli import main\n"
        f"try:\n    main({argv!r})\nexcept SystemExit:\n    pass\n"
        "print(' '.join(sorted(m for m in sys.modules if m.startswith('geoloc.cli.')"
        f" or any(m == h or m.startswith(h + '.') for h in {HEAVY!r}))))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return r.stdout.split("\n")[-2].split()


def _subparser_helps(parser) -> dict:
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    return {a.dest: a.help for a in sub._choices_actions}


def test_help_imports_no_verb_and_nothing_heavy():
    assert _imported_after(["--help"]) == []
    assert _imported_after([]) == []  # no verb: the help, exit 2


def test_a_verb_imports_its_own_module_only():
    mods = _imported_after(["locate", "--help"])
    assert "geoloc.cli.locate" in mods
    # its module and the shared options, no other verb
    assert [m for m in mods if m.startswith("geoloc.cli.")] == ["geoloc.cli._options", "geoloc.cli.locate"], mods


#: bench_startup.py's one-pixel locate (the docs' first example): one ray, the numpy path.
ONE_PIXEL = [
    "locate", "--lat-deg", "35.48", "--lon-deg", "80.97", "--h-m", "18000", "--heading-deg", "45",
    "--pitch-deg", "3.5", "--gimbal-roll-deg", "50", "--gimbal-pitch-deg", "-2.6", "--target-h-m", "5083.5", "--json",
]  # fmt: skip


def test_a_one_pixel_locate_imports_nothing_heavy():
    # one ray is below sensors.base.COMPILED_MIN_RAYS: no kernel is called, so numba (a quarter
    # of a second, and scipy with it) is not imported, nor PROJ, GDAL or a plot library
    mods = _imported_after(ONE_PIXEL)
    assert [m for m in mods if not m.startswith("geoloc.")] == [], mods
    assert "geoloc.cli.locate" in mods


def test_the_help_lines_are_the_verbs_own():
    # the lazy listing and every verb's own parser give the same line, from the one table
    lazy, full = _subparser_helps(build_parser(lazy=True)), _subparser_helps(build_parser())
    assert set(lazy) == set(full) == set(VERB_HELP), (sorted(lazy), sorted(VERB_HELP))
    for name, text in full.items():
        if name in VIEWER_VERBS and text != VERB_HELP[name]:  # the viewer not installed: says so
            assert text.startswith(VERB_HELP[name]) and "pip install ./viz" in text
        else:
            assert text == VERB_HELP[name] == lazy[name], name
