"""``geoloc report RESULTS.csv``: accuracy report (CEP, CE90, LE90, MAE, bias, trends) of a replay's output.

Reads the CSV that ``geoloc replay --out`` writes (flight-test records, MISB ST
0601 KLV or drone photos), measures the computed positions (``lat_deg``,
``lon_deg``, ``h_m``) against a reference (surveyed truth, the paper's positions
or the platform's reported frame centre) with :func:`geoloc.analysis.accuracy.accuracy_report`,
prints a table, and with ``--out-dir`` writes PNG plots, ``report.json`` and a
self-contained ``report.html`` (plots embedded as base64). See ``docs/report.md``.
"""

from __future__ import annotations

import argparse
import base64
import csv
import html
import json
import math
import os
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from geoloc.analysis.accuracy import (
    POSITION_RANGES,
    AccuracyReport,
    accuracy_report,
    out_of_range,
    position_kind,
    sight_geometry,
    track_azimuth_rad,
)
from geoloc.cli import VERB_HELP
from geoloc.cli._options import add_dem_options, add_sensor_option, input_path, output_dir, sensor_from_args
from geoloc.userfiles import atomic_path, write_text

if TYPE_CHECKING:
    from geoloc.analysis.height_audit import HeightAudit
    from geoloc.surfaces.base import Surface

#: Reference prefixes tried by ``--reference auto``, in this order.
AUTO_REFERENCES = ("truth", "reported", "paper")
#: Platform position columns (lat, lon, h) of each replay kind, in the order tried.
PLATFORM_COLUMNS = (("ac_lat_deg", "ac_lon_deg", "ac_h_m"), ("sensor_lat_deg", "sensor_lon_deg", "sensor_h_m"))
#: Heading columns (degrees), in the order tried (the track's fallback).
HEADING_COLUMNS = ("heading_deg", "platform_heading_deg")


#: A quick run of the verb that writes its files (a tuple: commands run in turn, the earlier ones make
#: its inputs): tests/cli/test_cli_rules.py runs it under every rule of docs/cli.md.
EXAMPLE = (
    "geoloc replay --height-column paper_height_m --out results.csv",
    "geoloc report results.csv --out-dir report",
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "report",
        help=VERB_HELP["report"],
        description="Accuracy of the computed positions of a `geoloc replay --out` CSV against a reference: "
        "per flight and overall, CEP (50th percentile of horizontal errors), CE90 / LE90 (90th percentiles "
        "of horizontal / |vertical| errors; numpy's linear percentile), mean absolute errors, the mean bias "
        "(north, east, up; along, across track), median errors against slant range, off-nadir angle and "
        "pixel radius, a linear error model in slant range and a datum warning. [Q17] eq. 18's radial RMS "
        "is a separate line. See docs/report.md.",
    )
    p.add_argument("results", metavar="RESULTS.csv", type=input_path, help="output CSV of `geoloc replay --out`")
    p.add_argument(
        "--reference",
        default="auto",
        choices=["auto", *AUTO_REFERENCES],
        help="reference positions: columns {ref}_lat_deg, {ref}_lon_deg (and {ref}_h_m); auto: the "
        "first of truth, reported (KLV frame centre), paper with values",
    )
    p.add_argument(
        "--ref-h-column",
        default=None,
        help="column of the reference's ellipsoidal height [m] (default {ref}_h_m, e.g. truth_h_m; "
        "without one the vertical error is not computed), e.g. paper_height_m for [Q17]",
    )
    p.add_argument(
        "--group-by",
        default=None,
        help="column grouping rows into flights (default: table, else file, else one group; 'none' for one group)",
    )
    add_sensor_option(
        p,
        help="camera/sensor file giving the image size for the pixel radius (default: the "
        "bundled [Q17] camera for flight-test records; none for other inputs)",
    )
    p.add_argument("--out-dir", default=None, type=output_dir, help="write PNG plots, report.json and report.html here")
    p.add_argument("--json", action="store_true", help="print the numbers as JSON (instead of the table)")
    p.add_argument(
        "--audit",
        action="store_true",
        help="with --dem: audit the flight's heights and conventions from the CSV's own poses and "
        "reported centres (records or KLV replays; a KLV replay also without --dem: the bearing check "
        "only; docs/height_audit.md): one line per finding, report.json's 'height_audit' and report.html",
    )
    p.set_defaults(func=run)

    add_dem_options(
        p,
        mosaic=False,
        tolerances=False,
        method_default="exact",
        dem_help="DEM raster for --audit (the one the replay used)",
    )


# --------------------------------------------------------------------------- reading


def read_results(path: str | os.PathLike[str]) -> tuple:
    """``(header, rows, messages)`` of a results CSV; ``rows`` are dicts with their line numbers (``_line``)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"results file {path} does not exist")
    from geoloc.io.records import check_header

    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            header, rows, messages = _read_rows(path, fh)
    except UnicodeDecodeError as e:
        raise ValueError(
            f"results file {path}: not a text CSV (UTF-8): byte 0x{e.object[e.start]:02x} cannot be "
            "decoded; is it a binary file?"
        ) from None
    check_header(path, header)
    # a position out of its range (latitude 95) leaves its row out, named, rather than stopping the report
    kept = []
    for row in rows:
        why = None
        for name in header:
            kind = position_kind(name)
            text = row.get(name, "")
            if kind is None or text == "":
                continue
            try:
                bad = bool(out_of_range(float(text), kind))
            except ValueError:
                continue  # not a number: said (and treated as missing) where the column is read
            if bad:
                lo, hi = POSITION_RANGES[kind]
                why = (
                    f"{path.name} line {row['_line']}: {name} = {text!r} is out of range [{lo:g}, {hi:g}]: row left out"
                )
                break
        if why:
            messages.append(why)
        else:
            kept.append(row)
    return header, kept, messages


def _read_rows(path, fh):
    reader = csv.reader(fh)
    header = next(reader, None)
    if header is None:
        raise ValueError(f"results file {path} is empty: it needs a header (the output of geoloc replay --out)")
    header = [h.strip() for h in header]
    rows, messages = [], []
    for line, values in enumerate(reader, start=2):
        if not values or all(not v.strip() for v in values):
            continue
        if len(values) != len(header):
            messages.append(f"{path.name} line {line}: {len(values)} fields, header has {len(header)}: skipped")
            continue
        row = dict(zip(header, (v.strip() for v in values)))
        row["_line"] = line
        rows.append(row)
    return header, rows, messages


def _column(rows, name, path, messages) -> np.ndarray:
    out = np.full(len(rows), np.nan)
    for k, r in enumerate(rows):
        text = r.get(name, "")
        if text == "":
            continue
        try:
            out[k] = float(text)
        except ValueError:
            messages.append(
                f"{path.name} line {r['_line']}: column {name} = {text!r} is not a number: treated as missing"
            )
    return out


def _has_values(rows, name) -> bool:
    return any(r.get(name, "") != "" for r in rows)


def report_from_csv(
    path: str | os.PathLike[str],
    reference: str = "auto",
    ref_h_column: str | None = None,
    group_by: str | None = None,
    camera: Any = None,
) -> tuple:
    """``(AccuracyReport, messages)`` of a replay output CSV (see the verb's help for the choices)."""
    path = Path(path)
    header, rows, messages = read_results(path)
    if not rows:
        raise ValueError(f"results file {path} has no data rows")
    for c in ("lat_deg", "lon_deg", "h_m"):
        if c not in header:
            raise ValueError(
                f"results file {path}: no column {c!r} (columns: {header}); give the output CSV of geoloc replay --out"
            )
    if reference == "auto":
        found = [p for p in AUTO_REFERENCES if _has_values(rows, f"{p}_lat_deg") and _has_values(rows, f"{p}_lon_deg")]
        if not found:
            raise ValueError(
                f"results file {path}: no reference columns with values ({', '.join(f'{p}_lat_deg' for p in AUTO_REFERENCES)}); "
                "the report needs truth or reported positions"
            )
        reference = found[0]
    for c in (f"{reference}_lat_deg", f"{reference}_lon_deg"):
        if c not in header:
            raise ValueError(f"results file {path}: --reference {reference} needs column {c!r}")
    col = lambda name: _column(rows, name, path, messages)
    n = len(rows)
    lat, lon, h = col("lat_deg"), col("lon_deg"), col("h_m")
    rlat, rlon = col(f"{reference}_lat_deg"), col(f"{reference}_lon_deg")
    if ref_h_column is None and f"{reference}_h_m" in header:
        ref_h_column = f"{reference}_h_m"
    if ref_h_column is not None and ref_h_column not in header:
        raise ValueError(f"results file {path}: --ref-h-column {ref_h_column!r} is not a column ({header})")
    rh = col(ref_h_column) if ref_h_column else np.full(n, np.nan)
    no_pos = ~(np.isfinite(lat) & np.isfinite(lon) & np.isfinite(h))
    if no_pos.any():
        st = [rows[k].get("status", "") for k in np.flatnonzero(no_pos)]
        lines = [rows[k]["_line"] for k in np.flatnonzero(no_pos)]
        messages.append(
            f"{path.name}: {int(no_pos.sum())} row(s) without a computed position, left out "
            f"(lines {_short(lines)}; status {', '.join(sorted(set(s for s in st if s))) or 'empty'})"
        )

    # groups
    if group_by is None:
        group_by = (
            "table"
            if "table" in header
            else ("file" if "file" in header and len({r.get("file") for r in rows}) > 1 else None)
        )
    elif group_by == "none":
        group_by = None
    elif group_by not in header:
        raise ValueError(f"results file {path}: --group-by {group_by!r} is not a column ({header})")
    group = [r.get(group_by, "") or "(empty)" for r in rows] if group_by else None

    # platform geometry: slant range, off-nadir angle, track
    plat = next((c for c in PLATFORM_COLUMNS if all(x in header for x in c)), None)
    slant = off = track = None
    if plat is not None:
        plat_lat, plat_lon, plat_h = (col(x) for x in plat)
        g = sight_geometry(plat_lat, plat_lon, plat_h, lat, lon, h)
        slant, off = g["slant_range_m"], g["off_nadir_rad"]
        hcol = next((c for c in HEADING_COLUMNS if c in header), None)
        heading = np.deg2rad(col(hcol)) if hcol else None
        track = track_azimuth_rad(plat_lat, plat_lon, group, heading)
    elif "slant_range_m" in header:
        slant = col("slant_range_m")
    if "track_heading_deg" in header:
        track = np.deg2rad(col("track_heading_deg"))

    # pixel radius from the image centre
    pix = None
    if "row" in header and "col" in header and (camera is not None or plat == PLATFORM_COLUMNS[0]):
        import argparse

        from geoloc.cli._options import sensor_from_args

        s = sensor_from_args(argparse.Namespace(camera=camera))
        r0, c0 = (s.rows + 1) / 2.0, (s.cols + 1) / 2.0
        pix = np.hypot(col("row") - r0, col("col") - c0)
    meta: dict[str, Any] = {
        "source": path.name,
        "reference": f"{reference}_lat_deg, {reference}_lon_deg"
        + (f", height {ref_h_column}" if ref_h_column else " (no reference height: vertical not computed)"),
        "group_by": group_by or "(one group)",
        "platform": ", ".join(plat) if plat else "(none: no slant range or off-nadir from geometry)",
        "track": (
            "track_heading_deg column"
            if "track_heading_deg" in header
            else "local azimuth between neighbouring platform positions, heading below 100 m"
            if plat
            else "(none)"
        ),
        "pixel_radius": "hypot(row - (rows+1)/2, col - (cols+1)/2) of the camera's image size"
        if pix is not None
        else "(none)",
        # the line-of-sight corrections the replay applied (its 'corrections' column), and how far
        # refraction moved the points (its 'refraction_m'): residuals judged with it on and off
        "corrections": ", ".join(sorted({r.get("corrections") or "none" for r in rows}))
        if "corrections" in header
        else "(not stated: a replay before the corrections)",
    }
    if "refraction_m" in header:
        shift = col("refraction_m")
        if np.isfinite(shift).any():
            meta["refraction_m_median"] = float(np.nanmedian(shift))
            meta["refraction_m_max"] = float(np.nanmax(shift))
    rep = accuracy_report(
        lat,
        lon,
        h,
        rlat,
        rlon,
        rh,
        track_heading_rad=track,
        slant_range_m=slant,
        off_nadir_rad=off,
        pixel_radius_px=pix,
        group=group,
        meta=meta,
    )
    if all(c in header for c in BUDGET_COLUMNS):
        add_budget_check(rep, *(col(c) for c in BUDGET_COLUMNS))
    return rep, messages


#: The replay CSV's predicted-uncertainty columns the budget check reads (``geoloc replay`` with a
#: sensor file's ``[uncertainty]``).
BUDGET_COLUMNS = ("ellipse_major_m", "ellipse_minor_m", "ellipse_azimuth_deg", "le90_m")


def add_budget_check(
    rep: AccuracyReport, major: np.ndarray, minor: np.ndarray, azimuth_deg: np.ndarray, le90: np.ndarray
) -> None:
    """The budget judged by the data (:func:`geoloc.analysis.uncertainty.budget_check`), overall and
    per group, into ``rep``: ``overall["budget"]``, each group's, and the per-target
    ``normalised_error`` (and ``normalised_vertical_error``) components."""
    from geoloc.analysis.uncertainty import budget_check

    c = rep.components

    def check(m):
        up = c["up_m"][m] if "up_m" in c else None
        return budget_check(
            c["east_m"][m], c["north_m"][m], major[m], minor[m], azimuth_deg[m], up, le90[m] if up is not None else None
        )

    allm = np.ones(len(major), bool)
    b = check(allm)
    c["normalised_error"] = b["normalised"]
    if "vertical" in b:
        c["normalised_vertical_error"] = b["vertical"]["normalised"]

    def strip(d: dict) -> dict:
        return {k: (strip(v) if isinstance(v, dict) else v) for k, v in d.items() if k != "normalised"}

    rep.overall["budget"] = strip(b)
    for g in rep.groups:
        rep.groups[g]["budget"] = strip(check(rep.group == g))
    rep.meta["budget_check"] = (
        "share of truths inside their own predicted 90 % ellipse (the replay's "
        "ellipse_* columns) against the binomial 99 % interval around 90 %; factor = "
        "90th percentile of error / its 90 % ellipse radius (geoloc.analysis.uncertainty)"
    )


def _short(lines) -> str:
    return ", ".join(str(x) for x in lines[:10]) + (f", ... ({len(lines)} in all)" if len(lines) > 10 else "")


# --------------------------------------------------------------------------- plots and HTML


def write_plots(rep: AccuracyReport, out_dir: str | os.PathLike[str]) -> list:
    """PNG plots (matplotlib, Agg) in ``out_dir``; returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    c, grp = rep.components, rep.group
    labels = list(dict.fromkeys(grp.tolist()))
    paths = []

    def save(fig, name):
        p = out_dir / name
        fig.tight_layout()
        with atomic_path(p) as tmp:
            fig.savefig(tmp, dpi=96)
        plt.close(fig)
        paths.append(p)

    # 1. horizontal error vectors (east, north) with the CEP / CE90 circles about the reference
    fig, ax = plt.subplots(figsize=(5.5, 5.0))
    for g in labels:
        m = grp == g
        ax.scatter(c["east_m"][m], c["north_m"][m], s=18, label=g)
    t = np.linspace(0, 2 * np.pi, 200)
    for key, style in (("cep_m", "-"), ("ce90_m", "--")):
        r = rep.overall[key]
        if math.isfinite(r):
            ax.plot(r * np.sin(t), r * np.cos(t), "k" + style, lw=0.8, label=f"{key[:-2].upper()} {r:.2f} m")
    ax.axhline(0, color="0.7", lw=0.5)
    ax.axvline(0, color="0.7", lw=0.5)
    ax.set_aspect("equal", "datalim")
    ax.set_xlabel("east error [m]")
    ax.set_ylabel("north error [m]")
    ax.set_title("horizontal error (computed - reference)")
    ax.legend(fontsize=7)
    save(fig, "errors_north_east.png")

    # 2. cumulative distribution of the horizontal and vertical errors
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    for key, lab in (("horizontal_m", "horizontal"), ("up_m", "|vertical|")):
        v = np.abs(c[key][np.isfinite(c[key])])
        if v.size:
            v = np.sort(v)
            ax.step(v, np.arange(1, v.size + 1) / v.size, where="post", label=lab)
    for key in ("cep_m", "ce90_m", "le90_m"):
        r = rep.overall[key]
        if math.isfinite(r):
            ax.axvline(r, color="0.5", lw=0.6, ls=":")
            ax.text(r, 0.02, key[:-2].upper(), rotation=90, fontsize=7)
    ax.set_xlabel("error [m]")
    ax.set_ylabel("fraction of targets")
    ax.set_title("cumulative errors")
    ax.legend(fontsize=7)
    save(fig, "errors_cdf.png")

    # 3-5. trends
    for key, xlabel in (
        ("slant_range_m", "slant range [m]"),
        ("off_nadir_deg", "off-nadir angle [deg]"),
        ("pixel_radius_px", "pixel radius from the image centre [px]"),
    ):
        if key not in c:
            continue
        fig, ax = plt.subplots(figsize=(5.5, 3.6))
        for g in labels:
            m = grp == g
            ax.scatter(c[key][m], c["horizontal_m"][m], s=14, label=g)
        bins = rep.overall.get(f"by_{key}") or []
        if bins:
            ax.plot(
                [b["x_median"] for b in bins], [b["median"] for b in bins], "k-o", ms=3, lw=1, label="binned median"
            )
        mdl = rep.overall.get("slant_range_model") if key == "slant_range_m" else None
        if mdl and math.isfinite(mdl["m_per_m"]):
            x = np.array([np.nanmin(c[key]), np.nanmax(c[key])])
            ax.plot(
                x,
                mdl["intercept_m"] + mdl["m_per_m"] * x,
                "r--",
                lw=1,
                label=f"{mdl['intercept_m']:.2f} m + {mdl['m_per_m'] * 1000:.3f} m/km",
            )
        ax.set_xlabel(xlabel)
        ax.set_ylabel("horizontal error [m]")
        ax.legend(fontsize=7)
        save(fig, f"error_vs_{key}.png")
    return paths


def _md_table_html(rep: AccuracyReport) -> str:
    cols = [
        ("n", "n", "d"),
        ("cep_m", "CEP [m]", ".2f"),
        ("ce90_m", "CE90 [m]", ".2f"),
        ("le90_m", "LE90 [m]", ".2f"),
        ("mae_horizontal_m", "MAE horizontal [m]", ".2f"),
        ("mae_vertical_m", "MAE vertical [m]", ".2f"),
        ("bias_north_m", "bias N [m]", ".2f"),
        ("bias_east_m", "bias E [m]", ".2f"),
        ("bias_up_m", "bias U [m]", ".2f"),
        ("bias_along_m", "bias along [m]", ".2f"),
        ("bias_across_m", "bias across [m]", ".2f"),
        ("radial_rms_eq18_m", "[Q17] eq. 18 radial RMS [m]", ".2f"),
    ]
    L = ["<table><tr><th>group</th>" + "".join(f"<th>{html.escape(t)}</th>" for _, t, _ in cols) + "</tr>"]
    for g, s in rep.rows():
        cells = []
        for key, _, spec in cols:
            v = s[key]
            cells.append("" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, spec))
        L.append(f"<tr><td>{html.escape(str(g))}</td>" + "".join(f"<td>{x}</td>" for x in cells) + "</tr>")
    L.append("</table>")
    return "\n".join(L)


def frame_runs(frames: Iterable[int]) -> str:
    """``"0 .. 4, 7 (6)"``: frame indices as runs of consecutive ones, and their count."""
    k = sorted(int(i) for i in frames)
    if not k:
        return "not said"
    runs, start = [], k[0]
    for a, b in zip(k, k[1:] + [k[-1] + 2]):  # a sentinel past the last run
        if b != a + 1:
            runs.append(f"{start}" if start == a else f"{start} .. {a}")
            start = b
    return f"{', '.join(runs)} ({len(k)})"


def write_html(rep: AccuracyReport, pngs: Sequence[str | os.PathLike[str]], path: str | os.PathLike[str]) -> Path:
    """One self-contained HTML page: the table, the definitions, the warnings and the plots (base64 PNG)."""
    path = Path(path)
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>geoloc accuracy report</title>",
        "<style>body{font-family:sans-serif;margin:1.5em;max-width:70em}table{border-collapse:collapse}"
        "td,th{border:1px solid #bbb;padding:2px 6px;text-align:right}th{background:#eee}"
        ".warn{color:#a00;font-weight:bold}img{max-width:48%;margin:4px}</style></head><body>",
        f"<h1>Accuracy report: {html.escape(str(rep.meta.get('source', '')))}</h1>",
        _md_table_html(rep),
    ]
    for w in rep.warnings:
        parts.append(f"<p class='warn'>warning: {html.escape(w)}</p>")
    for g, s in rep.rows():
        mdl = s.get("slant_range_model")
        if mdl and math.isfinite(mdl["m_per_m"]):
            parts.append(
                f"<p>{html.escape(str(g))}: horizontal error = {mdl['intercept_m']:.3f} m + "
                f"{mdl['m_per_m'] * 1000:.4f} m per km of slant range (least squares, n = {mdl['n']}, "
                f"RMS residual {mdl['rms_residual_m']:.2f} m)</p>"
            )
    audit = rep.meta.get("height_audit")
    if audit:
        parts.append(f"<h2>Heights and conventions: the audit of {html.escape(str(audit.get('source', '')))}</h2><ul>")
        for f in audit.get("findings") or []:
            parts.append(
                f"<li>{html.escape(str(f['text']))}; frames (rows of the CSV, from 0): "
                f"{html.escape(frame_runs(f.get('frames') or []))}</li>"
            )
        if not audit.get("findings"):
            parts.append("<li>no convention fault found</li>")
        parts.append("</ul>")
    parts.append("<h2>Definitions</h2><ul>")
    for k, v in rep.meta.items():
        if k == "height_audit":
            continue
        parts.append(f"<li><b>{html.escape(str(k))}</b>: {html.escape(str(v))}</li>")
    parts.append("</ul><h2>Plots</h2>")
    for p in pngs:
        b64 = base64.b64encode(Path(p).read_bytes()).decode("ascii")
        parts.append(f"<img alt='{html.escape(Path(p).stem)}' src='data:image/png;base64,{b64}'>")
    parts.append("<h2>Numbers (JSON)</h2><pre>" + html.escape(json.dumps(rep.to_dict(), indent=1)) + "</pre>")
    parts.append("</body></html>")
    write_text(path, "\n".join(parts))
    return path


# --------------------------------------------------------------------------- the verb


def _is_klv_results(path) -> bool:
    """Whether a results CSV is a KLV replay's (its header names the sensor and reported centres): its
    audit has a check that needs no DEM (the bearing of tag 18)."""
    import csv

    try:
        with Path(path).open(newline="", encoding="utf-8-sig") as fh:
            header = next(csv.reader(fh), [])
    except (OSError, UnicodeDecodeError):
        return False
    return all(c in header for c in ("sensor_lat_deg", "reported_lat_deg", "sensor_relative_azimuth_deg"))


def audit_from_csv(path: str | os.PathLike[str], surface: Surface | None, camera: str | None = None) -> HeightAudit:
    """The height audit (:mod:`geoloc.analysis.height_audit`) of a replay output CSV: a records replay
    (its pose columns, loaded as records with ``camera``'s angles; default the [Q17] camera) or a KLV
    replay (``sensor_*`` / ``reported_*`` columns; the frame centre's ray needs no field of view)."""

    from geoloc.analysis.height_audit import audit_klv_columns, audit_records

    header, rows, _ = read_results(path)
    if all(c in header for c in ("sensor_lat_deg", "reported_lat_deg", "sensor_relative_azimuth_deg")):
        from geoloc.status import Status
        from geoloc.workflows.klv_replay import klv_sensor

        cols = {}
        for name in header:
            if name == "status":
                cols[name] = np.array([Status[(r.get(name) or "invalid_input").upper()] for r in rows])
            elif name not in ("file", "time_utc", "note", "mgrs"):
                try:
                    cols[name] = np.array([float(r[name]) if r.get(name, "") != "" else np.nan for r in rows])
                except ValueError:
                    continue
        base = sensor_from_args(argparse.Namespace(camera=camera), default=False) if camera else None
        sens = klv_sensor(
            math.radians(float(np.nanmedian(cols["sensor_horizontal_fov_deg"]))),
            math.radians(float(np.nanmedian(cols["sensor_vertical_fov_deg"]))),
            base,
        )
        return audit_klv_columns(cols, sens, surface, source=Path(path).name)
    from geoloc.io.records import load_records

    sensor = sensor_from_args(argparse.Namespace(camera=camera))
    records = load_records(path, angles=sensor.angle_names)
    return audit_records(records, sensor, surface)


def run(args: argparse.Namespace) -> int:
    if args.audit and not args.dem and not _is_klv_results(args.results):
        raise ValueError("--audit compares heights with the terrain: give a DEM with --dem")
    rep, messages = report_from_csv(args.results, args.reference, args.ref_h_column, args.group_by, args.camera)
    audit = None
    if args.audit:
        from geoloc.cli._options import surface_from_args

        # a KLV replay without --dem: no terrain, the bearing check alone (audit_klv_columns says so)
        surface = surface_from_args(args) if args.dem else None
        audit = audit_from_csv(args.results, surface, args.camera)
        rep.meta["height_audit"] = audit.to_dict()
    for m in messages:
        print(f"geoloc report: {m}", file=sys.stderr)
    if args.json:
        print(json.dumps(rep.to_dict(), indent=1))
    else:
        print(rep.markdown())
        print(f"\nreference: {rep.meta['reference']}; heights ellipsoidal (WGS 84)")
    if audit is not None:
        print("\n".join(audit.lines()), file=sys.stderr if args.json else sys.stdout)
    if args.out_dir:
        out = Path(args.out_dir)
        pngs = write_plots(rep, out)
        write_text(out / "report.json", json.dumps(rep.to_dict(per_target=True), indent=1))
        page = write_html(rep, pngs, out / "report.html")
        print(
            f"wrote {page}, report.json and {len(pngs)} PNG plot(s) to {out}",
            file=sys.stderr if args.json else sys.stdout,
        )
    return 0
