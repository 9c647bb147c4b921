"""The command line's shared options are declared once, in geoloc.cli._options, so that they read and fail alike in every verb.

A verb module holds only what is its own: an option that several verbs share, declared
again in a verb, drifts (a missing --method, a different default, a help that lies).
Here every add_argument call of geoloc/cli is read from the source; each shared option
string may appear in one declaration only, in _options.py.
"""

import ast
from pathlib import Path

import pytest

from geoloc.cli import build_parser

CLI = Path(__file__).resolve().parents[2] / "geoloc" / "cli"

SHARED = (
    "--dem",
    "--dem-datum",
    "--dem-cache-mb",
    "--method",
    "--eps-h",
    "--threshold",
    "--dem-model",
    "--target-h-m",
    "--height-column",
    "--height-kind",
    "--sensor",
    "--camera",
    "--angle",
    "--altitude-datum",
    "--columns",
    "--lat-deg",
    "--lon-deg",
    "--h-m",
    "--heading-deg",
    "--gimbal-roll-deg",
    "--gimbal-pitch-deg",
)


def _declarations():
    """(file, line, option string) of every add_argument call in geoloc/cli."""
    out = []
    for path in sorted(CLI.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, "attr", None) == "add_argument":
                for a in node.args:
                    if isinstance(a, ast.Constant) and isinstance(a.value, str) and a.value.startswith("--"):
                        out.append((path.name, node.lineno, a.value))
    return out


@pytest.mark.parametrize("opt", SHARED)
def test_a_shared_option_is_declared_once(opt):
    where = [(f, ln) for f, ln, o in _declarations() if o == opt]
    assert len(where) == 1 and where[0][0] == "_options.py", f"{opt} declared at {where}"


def _verb_parsers():
    p = build_parser()
    sub = next(a for a in p._actions if a.dest == "verb")
    return sub.choices


@pytest.mark.parametrize("verb", ["locate", "replay", "ortho", "calibrate", "log", "montecarlo", "view"])
def test_every_verb_that_meets_the_ground_takes_the_dem_its_method_and_a_sensor(verb):
    opts = {s for a in _verb_parsers()[verb]._actions for s in a.option_strings}
    assert {"--dem", "--method", "--sensor", "--camera"} <= opts, sorted(opts)


@pytest.mark.parametrize("verb", ["locate", "replay", "ortho", "calibrate"])
def test_the_verbs_that_solve_any_dem_take_every_dem_option(verb):
    # these solve through geoloc.cli._options.open_surface: mosaics, tolerances and the DEM model
    opts = {s for a in _verb_parsers()[verb]._actions for s in a.option_strings}
    assert {"--dem-cache-mb", "--eps-h", "--threshold", "--dem-model", "--dem-datum"} <= opts, sorted(opts)


def test_calibrate_honours_the_dem_method(tmp_path):
    # before: calibrate --dem had no --method; now the steps method gives its own (coarser) hits,
    # so the residuals before calibration differ from the exact method's
    import json

    from geoloc.cli import main

    out = {}
    for m in ("exact", "steps"):
        o = tmp_path / f"{m}.json"
        assert (
            main(
                [
                    "calibrate",
                    "--dem",
                    "assets/dem/etopo5_flight_area.tif",
                    "--method",
                    m,
                    "--eps-h",
                    "50",
                    "--out",
                    str(o),
                ]
            )
            == 0
        )
        out[m] = json.loads(o.read_text())
    assert json.dumps(out["exact"]) != json.dumps(out["steps"])


def test_two_height_sources_are_refused(capsys):
    from geoloc.cli import main

    assert main(["calibrate", "--dem", "assets/dem/etopo5_flight_area.tif", "--target-h-m", "0"]) == 2
    assert "are both given" in capsys.readouterr().err


def test_a_mosaic_is_refused_where_one_raster_is_read(tmp_path, capsys):
    from geoloc.cli import main

    (tmp_path / "tiles").mkdir()
    rc = main(
        ["montecarlo", "assets/scenarios/qiao2017_table1.toml", "--dem", str(tmp_path / "tiles"), "--samples", "10"]
    )
    assert rc == 2 and "not a mosaic" in capsys.readouterr().err
