"""Options shared by the verbs: the path types every file option is declared with, and the DEM options.

**Files.** Every option that names a file is declared with one of three argparse
types, so that what a verb reads and writes is known from its declaration alone:
:func:`input_path` (a file or folder it reads; ``assets/...`` names the bundled file
where there is no such file here), :func:`output_path` (a file it writes) and
:func:`output_dir` (a folder it writes files into). :func:`geoloc.cli.main` reads
them (:func:`declared_files`) and checks every output against every input before
the verb runs (docs/architecture.md, "The user's files").

**DEM.** ``add_dem_options(parser)`` adds ``--dem FILE --method --dem-datum --eps-h
--threshold --dem-model --dem-cache-mb``; ``--dem`` is one raster, or a folder of
tiles, a ``.vrt`` or a repeated ``--dem``: a :class:`geoloc.surfaces.mosaic.DemMosaic`
(:func:`surface_from_args`, which also reads the target height options: the verb's one
:class:`~geoloc.surfaces.base.Surface`, beside :func:`sensor_from_args`'s sensor).
A verb on a DEM warns when the DEM's datum and the aircraft heights' datum look mixed
(:func:`warn_datums`).
Degrees and metres at this edge (docs/conventions.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from geoloc.assets import DEFAULT_CAMERA, asset_path, resolve_user_path
from geoloc.pipeline import TABLE_KEYS, Pipeline, corrections_from_table
from geoloc.surfaces.terrain import DEM_MODELS, METHODS
from geoloc.userfiles import STDOUT, check_output, check_output_dir, same_file

# --------------------------------------------------------------------------- file options


class StreamUrl(str):
    """A ``udp://HOST:PORT`` given where a file may be (``geoloc replay udp://...``): not a path,
    so it is neither noted as an input nor compared with the outputs."""


def input_path(text: str) -> str:
    """argparse type of an option naming a file or folder the verb reads.

    ``assets/...`` names the bundled file when there is no such file here
    (:func:`geoloc.assets.resolve_user_path`), so the README's commands run anywhere.
    A ``udp://`` URL (a live stream, docs/live.md) is returned as a :class:`StreamUrl`
    (the verb checks it: :func:`geoloc.io.live.parse_udp_url`, one line naming it).
    """

    if str(text).lower().startswith("udp://"):
        return StreamUrl(text)
    return str(resolve_user_path(text))


def is_stream(value) -> bool:
    """True for a :class:`StreamUrl` (or any ``udp://`` text)."""
    return isinstance(value, str) and value.lower().startswith("udp://")


def add_live_options(parser, record_flag: str = "--record") -> None:
    """When to stop a live input (``udp://``) and where to record it: ``--duration``, ``--packets``,
    ``--idle``, ``--record FILE.ts`` (docs/live.md)."""
    g = parser.add_argument_group("live input (udp://HOST:PORT, docs/live.md)")
    g.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="live: stop after S seconds (default: run until Ctrl-C, --packets or --idle)",
    )
    g.add_argument(
        "--packets", type=int, default=None, metavar="N", help="live: stop after N KLV packets (good and bad)"
    )
    g.add_argument(
        "--idle",
        type=float,
        default=None,
        metavar="S",
        help="live: stop when nothing arrived for S seconds after the first datagram",
    )
    g.add_argument(
        record_flag,
        dest="record_ts",
        default=None,
        metavar="FILE.ts",
        type=output_path,
        help="live: journal the raw stream, every datagram as it arrives, to this MPEG-TS "
        "(it grows as FILE.partial.ts and is renamed at the end; geoloc replay FILE.ts replays it)",
    )


def live_limits(args, url=None) -> dict:
    """The stop conditions of :func:`add_live_options`, checked (a bad value names its option), and
    ``url`` checked (:func:`geoloc.io.live.parse_udp_url`)."""
    if url is not None:
        from geoloc.io.live import parse_udp_url

        parse_udp_url(url)
    for opt, v in (("--duration", args.duration), ("--idle", args.idle)):
        if v is not None and not v > 0:
            raise ValueError(f"{opt} = {v}: must be > 0 seconds")
    if args.packets is not None and args.packets < 1:
        raise ValueError(f"--packets = {args.packets}: must be at least 1")
    return {"duration_s": args.duration, "packets": args.packets, "idle_s": args.idle}


def output_path(text: str) -> str:
    """argparse type of an option naming a file the verb writes (checked before the verb runs)."""
    return str(text)


def text_output_path(text: str) -> str:
    """argparse type of an option naming a text file the verb writes (CSV, JSON, TOML, KML ...):
    ``-`` is standard output there (docs/cli.md); elsewhere ``-`` is refused (a binary file)."""
    return str(text)


def output_dir(text: str) -> str:
    """argparse type of an option naming a folder the verb writes files into."""
    return str(text)


#: The role of each path type, as :func:`declared_files` reports it.
ROLES = {input_path: "input", output_path: "output", text_output_path: "output", output_dir: "output_dir"}


def chosen_parsers(parser, args) -> list:
    """The parser and the sub-parsers ``args`` went through (``geoloc klv dump``: three)."""
    out = [parser]
    while True:
        subs = [a for a in out[-1]._actions if isinstance(a, argparse._SubParsersAction)]
        name = getattr(args, subs[0].dest, None) if subs else None
        if not subs or name not in subs[0].choices:
            return out
        out.append(subs[0].choices[name])


def declared_files(parser, args, *, types: bool = False) -> tuple[list, list]:
    """The inputs and outputs of a parsed command line, from its options' types.

    Returns ``(inputs, outputs)``: ``inputs`` a list of paths, ``outputs`` a list of
    ``(option, path, role)`` with ``role`` ``"output"`` or ``"output_dir"`` (with
    ``types=True``, ``(option, path, role, type)``: the option's argparse type).
    """
    inputs, outputs = [], []
    for p in chosen_parsers(parser, args):
        for a in p._actions:
            role = ROLES.get(a.type)
            v = getattr(args, a.dest, None) if role else None
            if v is None:
                continue
            name = a.option_strings[0] if a.option_strings else a.metavar or a.dest
            for x in v if isinstance(v, list) else [v]:
                if role == "input" and is_stream(x):
                    continue  # a network stream is no file
                if role == "input":
                    inputs.append(x)
                else:
                    outputs.append((name, x, role, a.type) if types else (name, x, role))
    return inputs, outputs


def writes_stdout(parser, args) -> bool:
    """Whether an output of this command line is ``-`` (standard output)."""

    return any(path == STDOUT for _, path, _ in declared_files(parser, args)[1])


def check_outputs(parser, args) -> list:
    """Refuse, before the verb runs, an output that is an input or cannot be written; returns the inputs.

    ``-`` (standard output) is taken once, by an option whose file is text (:func:`text_output_path`);
    a binary output (GeoTIFF, GeoPackage, .rrd, MPEG-TS, PNG) given ``-`` is one clear error.
    """

    inputs, outputs = declared_files(parser, args, types=True)
    seen: dict[str, Any] = {}  # option name -> its path, or STDOUT
    for name, path, role, kind in outputs:
        if path == STDOUT:
            if kind is not text_output_path:
                raise ValueError(
                    f"{name} -: standard output is for text outputs (CSV, JSON, KML ...); "
                    f"{name} writes a binary file: give a file name"
                )
            if STDOUT in seen.values():
                other = next(k for k, v in seen.items() if v == STDOUT)
                raise ValueError(f"{other} - and {name} -: only one output can go to standard output")
            seen[name] = path
            continue
        (check_output if role == "output" else check_output_dir)(path, name, inputs=inputs)
        for other, q in seen.items():
            if q != STDOUT and same_file(path, q):
                raise ValueError(f"{name} {path} and {other} {q} are the same file: give two paths")
        seen[name] = path
    return inputs


# --------------------------------------------------------------------------- values checked before any work


def check_crs(option: str, value: str, words=("geographic", "utm")) -> str:
    """A CRS option checked before the verb computes anything (``--ortho-crs EPSG:99999`` once
    failed with a CRSError after the whole computation): one of ``words``, or a projected CRS in
    metres that pyproj knows. Returns ``value``; raises ``ValueError`` naming the option, the value
    and pyproj's reason."""
    if value in words:
        return value
    import pyproj

    try:
        crs = pyproj.CRS.from_user_input(value)
    except pyproj.exceptions.CRSError as e:
        reason = " ".join(str(e).split())
        raise ValueError(
            f"{option} {value!r}: not a CRS that pyproj knows ({reason}); give "
            f"{', '.join(words)} or a projected CRS such as EPSG:32617"
        ) from None
    if not crs.is_projected:
        raise ValueError(
            f"{option} {value!r} ({crs.name}) is not a projected CRS: its cells would be in "
            f"degrees, not metres; give {' or '.join(words)} or a projected CRS in metres"
        )
    units = {a.unit_name for a in crs.axis_info}
    if not units <= {"metre", "meter"}:
        raise ValueError(
            f"{option} {value!r} ({crs.name}): its unit is {', '.join(sorted(units))}, not metres; "
            "give a projected CRS in metres"
        )
    return value


def check_suffix(option: str, path, suffixes=(".tif", ".tiff"), what: str = "a GeoTIFF") -> None:
    """An output whose format is fixed, checked by its name before the verb computes anything
    (``--out frame.png`` of a verb that writes a GeoTIFF). ``None`` and ``-`` pass (``-`` is
    checked by :func:`check_outputs`)."""

    if path is None or path == "-":
        return
    if Path(path).suffix.lower() not in suffixes:
        raise ValueError(f"{option} {path}: must be {what} ({', '.join(suffixes)})")


def check_gis_output(option: str, path, format=None) -> None:
    """A GIS export's format (:func:`geoloc.io.gis.resolve_format`), told from its name before any
    work: ``replay --export x.shp`` failed only after every record was located."""
    if path is None or path == "-":
        return
    from geoloc.io.gis import resolve_format

    try:
        resolve_format(format, path)
    except ValueError as e:
        raise ValueError(f"{option} {path}: {e}") from None


# --------------------------------------------------------------------------- sensor, pose, records


def add_pose_options(g, required: bool = True, datum_what: str = "--h-m") -> None:
    """The aircraft's position and attitude (degrees, metres): ``--lat-deg`` ... ``--roll-deg``."""
    d = {"required": True} if required else {"default": None}
    g.add_argument("--lat-deg", type=float, **d, help="aircraft geodetic latitude [deg]")
    g.add_argument("--lon-deg", type=float, **d, help="aircraft longitude [deg, east +]")
    g.add_argument(
        "--h-m", type=float, **d, help="aircraft height [m]: ellipsoidal (WGS 84) unless --altitude-datum egm96 (MSL)"
    )
    add_altitude_datum_option(g, datum_what)
    g.add_argument("--heading-deg", type=float, default=0.0, help="heading psi [deg] (default 0)")
    g.add_argument("--pitch-deg", type=float, default=0.0, help="pitch theta, nose up + [deg]")
    g.add_argument("--roll-deg", type=float, default=0.0, help="roll phi, right wing down + [deg]")


def add_gimbal_options(g) -> None:
    """The gimbal's angles (the [Q17] pair, or ``--angle NAME=DEG``) and ``--sensor``."""
    g.add_argument(
        "--gimbal-roll-deg",
        type=float,
        default=None,
        help="[Q17] outer gimbal (roll) angle [deg]; negative looks right of track",
    )
    g.add_argument("--gimbal-pitch-deg", type=float, default=None, help="[Q17] inner gimbal (pitch) angle [deg]")
    add_angle_option(g)
    add_sensor_option(g)


def add_sensor_option(parser, help: str | None = None) -> None:
    """``--sensor FILE`` (alias ``--camera``): a sensor file, or a first-phase camera file."""
    parser.add_argument(
        "--sensor",
        "--camera",
        dest="camera",
        default=None,
        metavar="FILE",
        type=input_path,
        help=help
        or "sensor TOML ([lens], [gimbal], [mount], [lever_arm], [boresight]; "
        "docs/sensor_format.md) or a first-phase camera TOML "
        "(default: the bundled assets/cameras/qiao2017.toml)",
    )


def add_angle_option(parser) -> None:
    """``--angle NAME=DEG`` (repeatable): the sensor gimbal's joint angles by name."""
    parser.add_argument(
        "--angle",
        action="append",
        default=[],
        metavar="NAME=DEG",
        help="a gimbal joint angle in degrees, by the name the sensor's gimbal gives it "
        "(e.g. --angle azimuth=90 --angle elevation=-30); repeat for each joint",
    )


def add_altitude_datum_option(parser, what: str = "the records' ac_h_m") -> None:
    """``--altitude-datum ellipsoid|egm96``: the vertical datum of the aircraft heights."""
    from geoloc.io.columns import DATUMS

    parser.add_argument(
        "--altitude-datum",
        choices=list(DATUMS),
        default=None,
        help=f"vertical datum of the aircraft height ({what}): ellipsoid (WGS 84; the "
        "default, when not given) or egm96 (MSL, orthometric: made ellipsoidal with the "
        "bundled EGM96 grid, h = H + N); a column map's datum for ac_h_m wins",
    )


def add_columns_option(parser) -> None:
    """``--columns FILE``: a column map for the records CSV (docs/columns.md)."""
    parser.add_argument(
        "--columns",
        default=None,
        metavar="MAP.toml",
        type=input_path,
        help="column map: the records CSV's own column names and units (deg/rad, m/ft, "
        "ellipsoid/egm96 heights, zero-/one-based pixels) onto the canonical columns "
        "(docs/columns.md); default: the sensor file's [columns] table, if any",
    )


def add_records_options(parser) -> None:
    """The options of a verb that reads records: ``--columns`` and ``--altitude-datum``
    (read them with :func:`records_from_args`)."""
    add_columns_option(parser)
    add_altitude_datum_option(parser)


# --------------------------------------------------------------------------- target height


def add_target_options(parser, *, height_column: bool = True) -> None:
    """The target's height without a DEM: ``--target-h-m``, ``--height-column``, ``--height-kind``.

    ``--height-kind`` is the kind of constant-height surface (docs/architecture.md:
    the word *surface* is what a line of sight meets; this option chooses between
    the two height surfaces, :class:`geoloc.surfaces.height.HeightSurface`).
    """
    g = parser.add_argument_group("target height (without a DEM)")
    g.add_argument(
        "--target-h-m", type=float, default=None, help="one target height for every ray [m above the WGS 84 ellipsoid]"
    )
    if height_column:
        g.add_argument(
            "--height-column",
            default=None,
            help="column holding each target's height [m above the WGS 84 ellipsoid], e.g. paper_height_m",
        )
    g.add_argument(
        "--height-kind",
        choices=["inflated", "geodetic"],
        default="inflated",
        help="with a height: the ellipsoid inflated by it, [Q17] eq. 11 (default), or the exact "
        "surface of constant geodetic height",
    )


# --------------------------------------------------------------------------- DEM options


def dem_sources(args):
    """``--dem`` as given: one path (str) or, for a repeated ``--dem``, a list of paths."""
    return list(args.dem) if isinstance(args.dem, list) else args.dem


def _mosaic_options(args) -> dict:
    mb = getattr(args, "dem_cache_mb", 64.0)
    if not (np.isfinite(mb) and mb > 0):
        raise ValueError(f"--dem-cache-mb must be a positive number of MiB, got {mb!r}")
    return {"cache_bytes": max(int(mb * 2**20), 2**16)}


def surface_spec_from_args(args):
    """The :class:`~geoloc.surfaces.spec.SurfaceSpec` of the shared options, by value (a campaign
    sends it to its workers; :func:`surface_from_args` builds it here).

    ``--dem`` (its mosaics, ``--dem-datum``, ``--method``, ``--dem-model``, ``--eps-h``,
    ``--threshold``, ``--dem-cache-mb``), ``--target-h-m``, ``--height-column``, ``--height-kind``:
    each as the verb declares it (an option it does not declare keeps the solver's default).
    Two of ``--dem``, ``--height-column``, ``--target-h-m`` is an error naming them.
    """
    from geoloc.surfaces.spec import SurfaceSpec

    one_height_source(args)
    dem = getattr(args, "dem", None)
    return SurfaceSpec(
        dem=None if dem is None else (tuple(dem) if isinstance(dem, list) else dem),
        dem_datum=getattr(args, "dem_datum", None) or "egm96",
        method=getattr(args, "method", None) or "exact",
        dem_model=getattr(args, "dem_model", None) or "bilinear",
        eps_h=getattr(args, "eps_h", None),
        threshold=getattr(args, "threshold", None),
        cache_bytes=_mosaic_options(args)["cache_bytes"] if dem is not None and hasattr(args, "dem_cache_mb") else None,
        target_h_m=getattr(args, "target_h_m", None),
        height_column=getattr(args, "height_column", None),
        kind=getattr(args, "height_kind", None) or "inflated",
    )


def surface_from_args(args, records=None, *, example: str = "paper_height_m"):
    """The :class:`~geoloc.surfaces.base.Surface` of the shared options: the verb's one ground.

    ``--dem`` (one raster: a :class:`~geoloc.surfaces.terrain.DemSurface` of ``--method``,
    ``--dem-model``, ``--eps-h``, ``--threshold``; a folder, ``.vrt`` or repeated ``--dem``:
    the :class:`~geoloc.surfaces.mosaic.DemMosaic` itself), else ``--height-column`` (a
    :class:`~geoloc.surfaces.height.PerRecordHeightSurface` of ``records``), else
    ``--target-h-m`` (a :class:`~geoloc.surfaces.height.HeightSurface`), each of the
    ``--height-kind`` kind; two of them, or none, is an error naming the options.
    Built by :meth:`geoloc.surfaces.spec.SurfaceSpec.build` from :func:`surface_spec_from_args`
    (the DEM opened by ``open_dem_or_mosaic``, the choice :func:`geoloc.surfaces.terrain.surface_for`'s).
    """
    spec = surface_spec_from_args(args)
    if spec.dem is not None:
        return spec.build()
    column = spec.height_column
    if column is not None:
        if records is None:
            raise ValueError(f"--height-column {column}: this input has no records to read it from")
        h = records.column(column)
        bad = ~np.isfinite(h)
        if np.any(bad):
            raise ValueError(
                f"height column {column!r} is empty or not finite on line(s) {[int(n) for n in records.lines[bad]]}"
            )
        return spec.build(h)
    if spec.target_h_m is not None:
        return spec.build()
    given = "--height-column (e.g. " + example + "), " if hasattr(args, "height_column") else ""
    raise ValueError(f"give {given}--target-h-m or --dem")


def surface_from_scenario(model):
    """The :class:`~geoloc.surfaces.base.Surface` of a Monte Carlo scenario's ``[dem]`` table
    (``path``, ``datum``, ``method``), or None without one (the scenario's target height, with
    its error, is then Monte Carlo's own per-sample height surface).

    The same one way as :func:`surface_from_args`: a :class:`~geoloc.surfaces.spec.SurfaceSpec`
    built (``open_dem_or_mosaic``: a raster, or a folder / ``.vrt`` of tiles; then
    :func:`geoloc.surfaces.terrain.surface_for`).
    """
    if model.dem is None:
        return None
    from geoloc.surfaces.spec import SurfaceSpec

    return SurfaceSpec(dem=str(model.dem.path), dem_datum=model.dem.datum, method=model.dem.method or "exact").build()


def sensor_from_args(args, *, default: bool = True):
    """The sensor of ``--sensor`` / ``--camera``: the verb's one sensor, beside :func:`surface_from_args`.

    A sensor file, or a first-phase camera file, is a :class:`~geoloc.sensors.frame.FrameSensor`
    (:func:`geoloc.sensors.sensor_file.load_sensor`). Without the option: the
    bundled [Q17] camera, or None with ``default=False`` (a verb whose input brings its
    own sensor: KLV, photos).
    """
    from geoloc.sensors.sensor_file import load_sensor

    path = getattr(args, "camera", None)
    if not path and not default:
        return None
    return load_sensor(path if path else asset_path(*DEFAULT_CAMERA))


# --------------------------------------------------------------------------- progress of long work


def add_progress_options(parser) -> None:
    """``--progress`` / ``--no-progress`` of a long verb (:class:`geoloc.progress.Progress`, docs/cli.md).

    ``args.progress`` is None by default (the bar on a terminal, a line every 10 s elsewhere),
    True to force the bar, False for silence. ``tests/cli/test_cli_rules.py`` runs every verb that
    declares them with a clock that jumps and checks both forms of the progress.
    """
    parser.add_argument(
        "--progress",
        action="store_true",
        default=None,
        help="force the stderr progress bar (with the time left) on (default: the bar on a "
        "terminal; elsewhere, a log, a line every 10 s)",
    )
    parser.add_argument("--no-progress", dest="progress", action="store_false", default=None, help="no progress at all")


# --------------------------------------------------------------------------- line-of-sight corrections


def add_correction_options(parser) -> None:
    """``--refraction {none,standard}``, ``--no-light-time``, ``--no-aberration`` (docs/refraction.md).

    As in Orekit Rugged: refraction off unless asked for; light-time and aberration of light
    on for a spaceborne sensor, each with a flag to turn it off (and ``--light-time`` to turn
    light-time on for another sensor).
    """
    g = parser.add_argument_group("line-of-sight corrections (docs/refraction.md)")
    g.add_argument(
        "--refraction",
        choices=["none", "standard"],
        default=None,
        help="atmospheric refraction: none (default, as the papers) or standard (the ray bent "
        "through the U.S. Standard Atmosphere 1976)",
    )
    g.add_argument(
        "--light-time",
        dest="light_time",
        action="store_true",
        default=None,
        help="the Earth's rotation while the light travels (default: on for a spaceborne sensor)",
    )
    g.add_argument(
        "--no-light-time", dest="light_time", action="store_false", help="turn light-time off for a spaceborne sensor"
    )
    g.add_argument(
        "--no-aberration",
        dest="aberration",
        action="store_false",
        default=None,
        help="turn aberration of light off for a spaceborne sensor (on by default there)",
    )
    g.add_argument(
        "--ground-p-pa",
        dest="ground_p_pa",
        type=float,
        default=None,
        metavar="PA",
        help="with --refraction standard: the ground pressure measured [Pa] (the standard atmosphere fitted to it)",
    )
    g.add_argument(
        "--ground-t-k",
        dest="ground_t_k",
        type=float,
        default=None,
        metavar="K",
        help="with --refraction standard: the ground temperature measured [K]",
    )
    g.add_argument(
        "--ground-h-m",
        dest="ground_h_m",
        type=float,
        default=None,
        metavar="M",
        help="the height of that measurement [m] (default 0)",
    )


def corrections_from_args(args, sensor, settings: dict | None = None, base=None):
    """The verb's :class:`geoloc.pipeline.Corrections` for ``sensor``: the options of
    :func:`add_correction_options` over ``base`` (corrections a scenario already holds) or
    ``settings`` (a sensor or scenario file's ``[corrections]`` table: ``refraction``,
    ``light_time``, ``aberration``), over the sensor's defaults
    (:meth:`~geoloc.pipeline.Corrections.for_sensor`)."""

    flags = {k: getattr(args, k, None) for k in TABLE_KEYS}
    source = "[corrections] and the command line"
    if base is not None:  # the scenario's corrections, as the table that makes them
        from geoloc.corrections import GROUND_KEYS

        settings = base.to_table()
        if flags["refraction"] == "none":  # its ground measurement goes with its refraction
            settings = {k: v for k, v in settings.items() if k not in GROUND_KEYS}
    elif settings is None and getattr(args, "camera", None):  # the --sensor file's [corrections]
        from geoloc.sensors.sensor_file import load_sensor_corrections

        settings = load_sensor_corrections(args.camera)
    return corrections_from_table(sensor, settings, source, **flags)


def pipeline_from_args(args, sensor, surface, settings: dict | None = None):
    """The verb's one :class:`geoloc.pipeline.Pipeline`: its sensor, its surface and its corrections."""

    return Pipeline(sensor, surface, corrections_from_args(args, sensor, settings))


def warn_datums(verb: str, dem_datum: str, height) -> list:
    """Print (on stderr) and return the warnings of a DEM of ``dem_datum`` meeting aircraft heights
    read as ``height`` (a :class:`geoloc.io.columns.HeightSource`): see
    :func:`geoloc.io.columns.datum_warnings`."""
    from geoloc.io.columns import datum_warnings

    msgs = datum_warnings(dem_datum, height)
    for m in msgs:
        print(f"geoloc {verb}: warning: {m}", file=sys.stderr)
    return msgs


class _DemAction(argparse.Action):
    def __call__(self, parser, namespace, values, option_string=None):
        prev = getattr(namespace, self.dest, None) if getattr(namespace, "_dem_given", False) else None
        if prev is None:
            setattr(namespace, self.dest, values)  # one --dem: a path, as always
        else:  # --dem repeated: the files of one mosaic
            setattr(namespace, self.dest, (prev if isinstance(prev, list) else [prev]) + [values])
        setattr(namespace, "_dem_given", True)


def one_height_source(args) -> None:
    """Refuse two of ``--dem``, ``--height-column``, ``--target-h-m``: the targets lie on one of them."""
    given = [
        opt
        for opt, dest in (("--dem", "dem"), ("--height-column", "height_column"), ("--target-h-m", "target_h_m"))
        if getattr(args, dest, None) is not None
    ]
    if len(given) > 1:
        raise ValueError(f"{' and '.join(given)} are both given: the targets lie on one of them")


def one_dem_raster(args, verb: str):
    """``--dem`` of a verb that draws or samples one raster: its path (None without ``--dem``).

    A mosaic (a folder, a ``.vrt`` or a repeated ``--dem``) is refused with the option
    named, rather than read as something else.
    """

    if args.dem is None:
        return None
    if isinstance(args.dem, list) or Path(args.dem).is_dir() or str(args.dem).lower().endswith(".vrt"):
        shown = ", ".join(args.dem) if isinstance(args.dem, list) else args.dem
        what = "is a folder" if not isinstance(args.dem, list) and Path(args.dem).is_dir() else "is a mosaic"
        raise ValueError(
            f"--dem {shown} {what}: geoloc {verb} reads one DEM raster, not a mosaic (geoloc "
            "replay, locate, ortho and calibrate take mosaics)"
        )
    return args.dem


def add_dem_options(
    parser,
    *,
    mosaic: bool = True,
    tolerances: bool = True,
    datum: bool = True,
    method_default: str | None = "exact",
    dem_help: str | None = None,
    method_help: str | None = None,
) -> None:
    """The DEM options, declared here once for every verb that meets the terrain.

    The verb reads them with :func:`surface_from_args` (or, drawing one raster,
    :func:`one_dem_raster`). A verb declares only
    what it honours, so an option it would ignore does not exist for it:
    ``mosaic=False`` for a verb that reads one raster (no ``--dem-cache-mb``, no
    ``--dem-model``; :func:`one_dem_raster` refuses a folder or a ``.vrt``),
    ``tolerances=False`` for one that solves with the method's own defaults (no
    ``--eps-h``, ``--threshold``, ``--dem-model``), ``datum=False`` for one that
    reads every DEM as orthometric, EGM96 (no ``--dem-datum``). ``method_default=None``: the
    verb's own default (a scenario's method) when ``--method`` is not given.
    """
    g = parser.add_argument_group("terrain (DEM)")
    g.add_argument(
        "--dem",
        metavar="FILE",
        default=None,
        action=_DemAction,
        type=input_path,
        help=dem_help
        or "DEM raster (GeoTIFF, ...): intersect the line of sight with the terrain "
        "instead of a target height, e.g. assets/dem/etopo5_flight_area.tif"
        + (
            "; a folder of tiles, a GDAL .vrt, or --dem given several times is one mosaic, read in "
            "windows on demand (docs/scale.md)"
            if mosaic
            else ""
        ),
    )
    if mosaic:
        g.add_argument(
            "--dem-cache-mb",
            type=float,
            default=64.0,
            help="DEM mosaic: bound of its tile cache and of one region it assembles [MiB] (default 64)",
        )
    g.add_argument(
        "--method",
        choices=METHODS,
        default=method_default,
        help=method_help
        or "steps: descending steps of [Q17]; bisect: halving of [L23]; "
        "exact: first visible hit, no threshold (default)",
    )
    if datum:
        g.add_argument(
            "--dem-datum",
            choices=["egm96", "ellipsoid"],
            default="egm96",
            help="vertical datum of the DEM heights (default egm96: real DEMs are orthometric; "
            "N from the bundled EGM96 grid)",
        )
    if tolerances:
        g.add_argument("--eps-h", type=float, default=1.0, help="step of --method steps [m] (default 1)")
        g.add_argument(
            "--threshold", type=float, default=1.0, help="bisection stops when |H - h_DEM| < threshold [m] (default 1)"
        )
    if tolerances and mosaic:
        g.add_argument(
            "--dem-model",
            dest="dem_model",
            choices=DEM_MODELS,
            default="bilinear",
            help="how the exact method reads between DEM nodes: bilinear cells (default) or two triangles per cell",
        )
