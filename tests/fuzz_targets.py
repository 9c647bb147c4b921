"""The parsers' fuzz targets, shared by the suite and the long run.

Each target takes bytes (a whole input file), mutated from a real seed (a bundled file, or
one written by the format's own standard layout); it feeds them to one parser and checks
the parser's promise:

- nothing raises but the documented clear errors: ``ValueError`` (``KlvError``,
  ``PhotoTagError``, ``OutputRefused`` ...) or ``OSError`` (what ``geoloc.cli.main`` turns
  into one line), with a message that names the file or the field (:func:`check_error`);
  a bare library error (``KeyError``, ``TypeError``, ``IndexError``, ``struct.error``,
  ``UnicodeDecodeError``, a message without the file) is a finding;
- good records around a bad one are kept (the records CSV: every line the mutation left
  alone and that was good is still loaded; KLV and MPEG-TS: tests/io/test_klv_wild.py).

The in-suite tests (tests/io/test_fuzz.py) run every target with hypothesis for a few seconds
and replay the corpus (``tests/data/fuzz/TARGET/*``: the inputs the long run found,
kept as regression cases); the long run is ``python tools/fuzz.py --minutes 10 --seed 0``
(docs/testing.md, "Fuzzing").
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[1]
ASSETS = ROOT / "assets"
CORPUS = ROOT / "tests" / "data" / "fuzz"

#: Tokens a mutation puts in place of a field of a text format: the values that break parsers.
TOKENS = [
    "",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "1e309",
    "-1e309",
    "-0",
    "0",
    "-1",
    "1e-320",
    "9" * 40,
    "0x10",
    "1_0",
    "+",
    "-",
    ".",
    "e",
    '"',
    "'",
    ",",
    ";",
    "=",
    "[",
    "]",
    "{",
    "}",
    "[[",
    "#",
    "\\",
    "\x00",
    "\ufeff",
    "é",
    "\u202e",
    "\r",
    "\n",
    "\t",
    "true",
    "false",
    "[]",
    "{}",
    '""',
    "1979-05-27T07:32:00Z",
    "[lens]",
    "[columns]",
    "model",
    "brown",
    "x" * 300,
]


# --------------------------------------------------------------------------- mutations


def apply_byte_ops(seed: bytes, ops) -> bytes:
    """Apply byte mutations: (kind, position, bytes, count) each."""
    b = bytearray(seed)
    for kind, pos, data, n in ops:
        pos = pos % (len(b) + 1)
        if kind == "flip" and pos < len(b):
            b[pos] ^= 1 << (n % 8)
        elif kind == "set" and pos < len(b):
            b[pos : pos + len(data)] = data
        elif kind == "insert":
            b[pos:pos] = data
        elif kind == "delete":
            del b[pos : pos + n]
        elif kind == "dup":
            b[pos:pos] = b[pos : pos + n]
        elif kind == "truncate":
            del b[pos:]
    return bytes(b)


def byte_mutations(seed: bytes, max_ops: int = 4, window: int | None = None):
    """Strategy: ``seed`` with a few byte mutations (within its first ``window`` bytes)."""
    span = len(seed) if window is None else min(window, len(seed))
    op = st.tuples(
        st.sampled_from(["flip", "set", "insert", "delete", "dup", "truncate"]),
        st.integers(0, span),
        st.binary(min_size=1, max_size=8),
        st.integers(0, 64),
    )
    return st.lists(op, min_size=1, max_size=max_ops).map(lambda ops: apply_byte_ops(seed, ops))


def apply_text_ops(seed: str, ops) -> str:
    """Apply field mutations to text: (line, field, token, kind) each; fields split on , = and blanks."""
    import re

    lines = seed.split("\n")
    for li, fi, token, kind in ops:
        li %= len(lines)
        parts = re.split(r"([,=\s]+)", lines[li])
        fields = list(range(0, len(parts), 2))
        f = fields[fi % len(fields)]
        if kind == "replace":
            parts[f] = token
        elif kind == "append":
            parts[f] += token
        elif kind == "line":
            lines.insert(li, token)
            continue
        elif kind == "drop_line":
            del lines[li]
            if not lines:
                lines = [""]
            continue
        lines[li] = "".join(parts)
    return "\n".join(lines)


def text_mutations(seed: str, max_ops: int = 3, lines=None):
    """Strategy: ``seed`` with a few fields replaced by :data:`TOKENS` (or random text), as UTF-8 bytes.

    ``lines``: (first, last) 0-based lines the mutations may touch (default: all)."""
    n = len(seed.split("\n"))
    lo, hi = lines if lines else (0, n - 1)
    token = st.one_of(st.sampled_from(TOKENS), st.text(max_size=12))
    op = st.tuples(
        st.integers(lo, hi),
        st.integers(0, 40),
        token,
        st.sampled_from(["replace", "replace", "append", "line", "drop_line"]),
    )
    return st.lists(op, min_size=1, max_size=max_ops).map(
        lambda ops: apply_text_ops(seed, ops).encode("utf-8", "surrogatepass")
    )


def any_mutation(seed: bytes, text: bool, window: int | None = None):
    """Field mutations for a text format, byte mutations for any, and now and then random bytes."""
    parts = [byte_mutations(seed, window=window), st.binary(max_size=256)]
    if text:
        parts.insert(0, text_mutations(seed.decode("utf-8")))
    return st.one_of(*parts)


# --------------------------------------------------------------------------- the promise


class Finding(AssertionError):
    """A parser broke its promise on one input."""


#: Library messages that name no file and no field: an error with only this to say is a finding.
_BARE = (
    "codec can't decode",
    "invalid literal for int()",
    "could not convert string to float",
    "list index out of range",
    "unpack requires",
    "NoneType",
    "not subscriptable",
    "object has no attribute",
    "math domain error",
    "division by zero",
)


def check_error(e: BaseException, names=()) -> None:
    """Raise :class:`Finding` unless ``e`` is a documented clear error naming one of ``names``.

    ``names``: what the message may name (the file's name, the field); any one is enough.
    """
    from geoloc.extras import MissingExtra

    ok_type = isinstance(e, (ValueError, OSError, MissingExtra)) and not isinstance(e, UnicodeError)
    msg = str(e)
    if not ok_type:
        raise Finding(f"{type(e).__name__} escaped: {msg}") from e
    if names and not any(str(n) in msg for n in names):
        raise Finding(f"{type(e).__name__}: message names none of {list(names)}: {msg!r}") from e
    if not msg.strip() or (not names and any(b in msg for b in _BARE)):
        raise Finding(f"{type(e).__name__} with a bare library message: {msg!r}") from e


#: Called with each clear error (tools/fuzz.py counts the distinct ones and keeps an input of each).
OBSERVER = None


def expect_clear(fn, names=()):
    """Run ``fn()``; an exception must be a clear one (:func:`check_error`). Returns fn's value or None."""
    try:
        return fn()
    except Finding:
        raise
    except (KeyboardInterrupt, SystemExit, MemoryError):
        raise
    except BaseException as e:  # noqa: BLE001 - every other exception is judged
        check_error(e, names)
        if OBSERVER is not None:
            OBSERVER(e)
        return None


def _in_file(data: bytes, name: str, fn: Callable[[Path], object]):
    """Write ``data`` to a temporary file called ``name`` and call ``fn(path)``."""
    with tempfile.TemporaryDirectory(prefix="geoloc-fuzz-") as d:
        p = Path(d) / name
        p.write_bytes(data)
        return fn(p)


# --------------------------------------------------------------------------- targets


def _seed(*parts) -> bytes:
    return (ASSETS.joinpath(*parts)).read_bytes()


def klv_seed() -> bytes:
    """The first 40 packets of the bundled example flight (its one planted bad checksum is later)."""
    from geoloc.io.klv import iter_packets

    data = _seed("klv", "example_flight.klv")
    offsets = [p.offset for _, p in zip(range(41), iter_packets(data, verify_checksum=False))]
    return data[: offsets[-1]]


def run_klv(data: bytes) -> None:
    from geoloc.io.klv import KlvError, Packet, iter_packets

    def go():
        out = list(iter_packets(data))
        bad = [x for x in out if not isinstance(x, (Packet, KlvError))]
        if bad:
            raise Finding(f"iter_packets yielded {type(bad[0]).__name__}")
        for x in out:
            if isinstance(x, Packet):
                x.to_json()
        return out

    expect_clear(go)


def ts_seed() -> bytes:
    """20 packets of the example flight in an MPEG-TS as a multiplexer writes asynchronous KLV
    (tests/ts_builder.py: PAT, PMT with the KLVA registration, one PES per packet)."""
    from geoloc.io.klv import iter_packets
    from ts_builder import stream

    data = klv_seed()
    offsets = [p.offset for p in iter_packets(data, verify_checksum=False)] + [len(data)]
    return stream([data[a:b] for a, b in zip(offsets[:20], offsets[1:21])])


def run_ts(data: bytes) -> None:
    from geoloc.io.klv import KlvError, Packet, read_ts_klv
    from geoloc.io.ts_demux import TsDemuxer

    def go(p):
        for x in read_ts_klv(p):
            if not isinstance(x, (Packet, KlvError)):
                raise Finding(f"read_ts_klv yielded {type(x).__name__}")

    _in_file(data, "flight.ts", lambda p: expect_clear(lambda: go(p), [p.name]))

    def live():  # the live demuxer, fed as datagrams of 7 TS packets
        d = TsDemuxer()
        for i in range(0, len(data), 1316):
            d.feed_datagram(data[i : i + 1316])
        d.flush()

    expect_clear(live)


def _real_packets() -> list[bytes]:
    """The first three packets of each real file of tests/data/misb (four writers: Esri, Tekever,
    FFmpeg's two samples; security sets, reserved values, tag 22 in 4 bytes), in file order."""
    from geoloc.io.klv import iter_packets

    out = []
    for name in (
        "esri_cheyenne.bin",
        "tekever_ar5_realflight.bin",
        "ffmpeg_day_flight.klv",
        "ffmpeg_night_flight_ir.klv",
    ):
        data = (ROOT / "tests" / "data" / "misb" / name).read_bytes()
        offsets = [p.offset for _, p in zip(range(4), iter_packets(data))]
        out += [data[a:b] for a, b in zip(offsets, offsets[1:])]
    return out


def klv_real_seed() -> bytes:
    return b"".join(_real_packets())


def run_klv_real(data: bytes) -> None:
    """run_klv, and every real packet the mutation left whole, where it starts after the end of
    the one before it, is still decoded at its offset (a bad packet never takes a good one
    with it)."""
    from geoloc.io.klv import Packet, iter_packets

    run_klv(data)
    got = {x.offset for x in iter_packets(data) if isinstance(x, Packet)}
    pos = 0
    for pk in _real_packets():
        at = data.find(pk, pos)
        if at < 0:
            continue
        if at not in got:
            raise Finding(f"the whole real packet at byte {at} was not decoded")
        pos = at + len(pk)


def ts_real_seed() -> bytes:
    """The real packets in an MPEG-TS with no PAT / PMT (found by their keys)."""
    from ts_builder import stream

    return stream(_real_packets(), psi=False)


def csv_seed() -> bytes:
    return b"".join(_seed("records", "eo_turret_flight.csv").splitlines(keepends=True)[:12])


def _turret_map():
    return {"ac_h_m": {"column": "ac_h_m", "datum": "ellipsoid"}, "row": "row", "col": "col"}


def run_csv(data: bytes, seed: bytes | None = None) -> None:
    """Records CSV with a column map: a clear error, or the good rows kept with a reason per bad one."""
    from geoloc.io.records import load_records

    seed = csv_seed() if seed is None else seed
    angles = ("azimuth", "elevation")

    def go(p):
        r = expect_clear(lambda: load_records(p, angles=angles, columns=_turret_map()), [p.name])
        if r is None:
            return
        for e in r.errors:
            if not str(e).strip() or e.line < 1:
                raise Finding(f"a rejected row without its line or reason: {e!r}")
        _good_rows_kept(data, seed, r)

    _in_file(data, "flight.csv", go)


def _good_rows_kept(data: bytes, seed: bytes, r) -> None:
    """When the header is the seed's and lines were only changed in place, every line left as it
    was (a good row in the seed) is loaded, at its line number."""
    new, old = data.split(b"\n"), seed.split(b"\n")
    if len(new) != len(old) or new[0] != old[0] or b"\r" in data or b'"' in data:
        return
    loaded = set(int(x) for x in r.lines)
    for k in range(1, len(old)):
        if new[k] == old[k] and old[k].strip():
            if k + 1 not in loaded:
                raise Finding(
                    f"line {k + 1}, unchanged and good, was not loaded (errors: {[str(e) for e in r.errors][:3]})"
                )


def column_map_seed() -> bytes:
    return (
        b'[columns]\nac_lat_deg = "Latitude"\nac_lon_deg = "Longitude"\n'
        b'ac_h_m = {column = "Alt_ft", unit = "ft", datum = "egm96"}\n'
        b'heading_deg = {column = "Yaw", unit = "rad"}\nazimuth_deg = "TurretAz"\n'
        b'row = "PixelY"\ncol = {column = "PixelX", pixel = "zero-based"}\n'
    )


_MAPPED_CSV = (
    "Latitude,Longitude,Alt_ft,Yaw,pitch_deg,roll_deg,TurretAz,elevation_deg,PixelY,PixelX\n"
    "36.6,-84.25,8200,1.57,2.0,1.4,93.6,-9.7,598,842\n"
    "36.61,-84.24,8210,1.58,2.0,1.4,93.7,-9.8,599,843\n"
)


def run_column_map(data: bytes) -> None:
    from geoloc.io.columns import load_column_map
    from geoloc.io.records import load_records

    def go(d):
        m = d / "map.toml"
        m.write_bytes(data)
        csv = d / "log.csv"
        csv.write_text(_MAPPED_CSV)
        cmap = expect_clear(lambda: load_column_map(m), [m.name])
        if cmap is not None:
            expect_clear(
                lambda: load_records(csv, angles=("azimuth", "elevation"), columns=cmap), [m.name, csv.name, "column"]
            )

    with tempfile.TemporaryDirectory(prefix="geoloc-fuzz-") as d:
        go(Path(d))


def sensor_seed() -> bytes:
    return _seed("sensors", "eo_turret.toml")


def run_sensor(data: bytes) -> None:
    from geoloc.sensors.sensor_file import load_sensor, load_sensor_budget, load_sensor_columns

    def go(p):
        s = expect_clear(lambda: load_sensor(p), [p.name])
        if s is not None:
            import numpy as np

            expect_clear(
                lambda: (
                    s.lens.project_undistorted(np.array([[0.0, 0.0, 1.0]]))
                    if hasattr(s.lens, "project_undistorted")
                    else None
                )
            )
        expect_clear(lambda: load_sensor_budget(p), [p.name])
        expect_clear(lambda: load_sensor_columns(p), [p.name])

    _in_file(data, "sensor.toml", go)


SCENARIOS = ("qiao2017_table1.toml", "qiao2017_frame.toml", "tiangong2_limb.toml", "zy3_nadir.toml", "flight_scan.toml")


def scenario_seed(name: str) -> bytes:
    return _seed("scenarios", name)


def run_scenario(data: bytes) -> None:
    from geoloc.workflows.scenario import load_scenario

    def go(d: Path):
        p = d / "scenario.toml"
        p.write_bytes(data)
        for sub in ("dem", "sensors", "records", "cameras", "geoid"):  # relative paths the bundled ones name
            (d / sub).symlink_to(ASSETS / sub)
        expect_clear(lambda: load_scenario(p), [p.name])

    with tempfile.TemporaryDirectory(prefix="geoloc-fuzz-") as d:
        go(Path(d))


def photo_seed() -> bytes:
    return _seed("photos", "DJI_0001.JPG")


def run_photo(data: bytes) -> None:
    from geoloc.io.photos import pose_from_photo, read_photo, sensor_from_photo

    def go(p):
        m = expect_clear(lambda: read_photo(p), [p.name])
        if m is not None:
            expect_clear(lambda: sensor_from_photo(m), [p.name])
            expect_clear(lambda: pose_from_photo(m), [p.name])

    _in_file(data, "DJI_0001.JPG", go)


def xmp_seed() -> bytes:
    from geoloc.io.photos import read_xmp_packet

    return read_xmp_packet(ASSETS / "photos" / "DJI_0001.JPG")


def run_xmp(data: bytes) -> None:
    from geoloc.io.photos import parse_xmp

    expect_clear(lambda: parse_xmp(data, source="photo.jpg XMP"), ["photo.jpg"])


def rpc_seed() -> bytes:
    """An RPC00B text file (GeoEye / Ikonos ``NAME_rpc.txt``) of a well-formed model."""
    lines = []
    vals = {
        "LINE_OFF": "+5000.0 pixels",
        "SAMP_OFF": "+5000.0 pixels",
        "LAT_OFF": "+36.5 degrees",
        "LONG_OFF": "-84.2 degrees",
        "HEIGHT_OFF": "+500.0 meters",
        "LINE_SCALE": "+5000.0 pixels",
        "SAMP_SCALE": "+5000.0 pixels",
        "LAT_SCALE": "+0.1 degrees",
        "LONG_SCALE": "+0.12 degrees",
        "HEIGHT_SCALE": "+500.0 meters",
    }
    lines += [f"{k}: {v}" for k, v in vals.items()]
    coef = {
        "LINE_NUM": [0.001, -0.02, -1.0, 0.0001],
        "LINE_DEN": [1.0, 0.0001],
        "SAMP_NUM": [-0.002, 1.0, -0.01, 0.0002],
        "SAMP_DEN": [1.0, 0.0, 0.0002],
    }
    for k, c in coef.items():
        c = (c + [0.0] * 20)[:20]
        lines += [f"{k}_COEFF_{i + 1}: {v:+.15e}" for i, v in enumerate(c)]
    return ("\n".join(lines) + "\n").encode()


def run_rpc_text(data: bytes) -> None:
    """The RPC00B text through GDAL's parser (``read_rpc``) and through our own (``RPCModel.from_gdal``)."""
    from geoloc.io.rpc_gdal import read_rpc
    from geoloc.sensors.rpc import RPCModel

    _in_file(data, "scene_RPC.TXT", lambda p: expect_clear(lambda: read_rpc(p, rows=10000, cols=10000), [p.name]))
    md = {}
    for line in data.decode("utf-8", "replace").splitlines():
        if ":" in line:
            k, v = line.split(":", 1)
            k = k.strip()
            if "_COEFF_" in k:
                base = k.rsplit("_", 1)[0]
                md[base] = (md.get(base, "") + " " + v.strip().split(" ")[0]).strip()
            else:
                md[k] = v.strip()
    expect_clear(lambda: RPCModel.from_gdal(md), ["RPC metadata"])


def nitf_seed() -> bytes:
    """A 16 x 16 NITF 2.1 whose RPC00B TRE carries the model of :func:`rpc_seed` (GDAL writes it)."""
    import rasterio  # noqa: F401 - GDAL

    from geoloc.io.rpc_gdal import write_rpc_nitf
    from geoloc.sensors.rpc import RPCModel

    md = {}
    for line in rpc_seed().decode().splitlines():
        k, v = line.split(":", 1)
        if "_COEFF_" in k:
            base = k.rsplit("_", 1)[0]
            md[base] = (md.get(base, "") + " " + v.strip()).strip()
        else:
            md[k] = v.strip()
    with tempfile.TemporaryDirectory(prefix="geoloc-fuzz-") as d:
        p = Path(d) / "scene.ntf"
        write_rpc_nitf(p, RPCModel.from_gdal(md), 16, 16)
        return p.read_bytes()


def run_nitf(data: bytes) -> None:
    from geoloc.io.rpc_gdal import read_rpc

    _in_file(data, "scene.ntf", lambda p: expect_clear(lambda: read_rpc(p), [p.name]))


LENS_SEEDS = {
    "opencv.yml": b"%YAML:1.0\n---\nimage_width: 1280\nimage_height: 960\ncamera_matrix: !!opencv-matrix\n"
    b"   rows: 3\n   cols: 3\n   dt: d\n   data: [ 1.2104e+03, 0., 6.4130e+02, 0., 1.2045e+03, "
    b"4.7820e+02, 0., 0., 1. ]\ndistortion_coefficients: !!opencv-matrix\n   rows: 5\n   cols: 1\n"
    b"   dt: d\n   data: [ -8.0e-02, 2.0e-02, 2e-4, -1e-4, -2.0e-03 ]\n",
    "cameras.txt": b"# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n1 SIMPLE_PINHOLE 640 480 500.0 320.0 240.0\n"
    b"2 OPENCV 640 480 500.0 501.0 320.0 240.0 -0.2 0.04 1e-3 -5e-4\n"
    b"3 OPENCV_FISHEYE 848 800 285.0 285.7 425.1 400.8 -0.0073 0.044 -0.042 0.0078\n",
    "camera_models.json": b'{"brown cam": {"projection_type": "brown", "width": 1200, "height": 1600, '
    b'"focal_x": 0.8, "focal_y": 0.81, "c_x": 0.01, "c_y": -0.02, "k1": -0.1, "k2": 0.02, '
    b'"k3": -0.001, "p1": 0.001, "p2": -0.0005}}',
}


def _lens_target(name):
    def run(data: bytes) -> None:
        from geoloc.sensors.lens_io import read_lens_file

        def go(p):
            cam = 1 if name == "cameras.txt" else ("brown cam" if name.endswith(".json") else None)
            expect_clear(lambda: read_lens_file(p, camera=cam), [p.name])

        _in_file(data, name, go)

    return Target(f"lens_{name.split('.')[0]}", lambda: LENS_SEEDS[name], run, True, Path(name).suffix)


@dataclass(frozen=True)
class Target:
    """A parser under fuzzing: its seed input, how to mutate it, how to run it, the corpus suffix."""

    name: str
    seed: Callable[[], bytes]
    run: Callable[[bytes], None]
    text: bool
    suffix: str
    window: int | None = None  # byte mutations only in the first ``window`` bytes (a photo's metadata)

    def strategy(self):
        return any_mutation(self.seed(), self.text, self.window)


def _scenario_target(name):
    return Target(f"scenario_{Path(name).stem}", lambda: scenario_seed(name), run_scenario, True, ".toml")


TARGETS = {
    t.name: t
    for t in [
        Target("klv", klv_seed, run_klv, False, ".klv"),
        Target("ts", ts_seed, run_ts, False, ".ts"),
        Target("klv_real", klv_real_seed, run_klv_real, False, ".klv"),
        Target("ts_real", ts_real_seed, run_ts, False, ".ts"),
        Target("csv", csv_seed, run_csv, True, ".csv"),
        Target("column_map", column_map_seed, run_column_map, True, ".toml"),
        Target("sensor", sensor_seed, run_sensor, True, ".toml"),
        *[_scenario_target(n) for n in SCENARIOS],
        Target("photo", photo_seed, run_photo, False, ".jpg", window=20000),
        Target("xmp", xmp_seed, run_xmp, True, ".xmp"),
        Target("rpc_text", rpc_seed, run_rpc_text, True, ".txt"),
        Target("nitf", nitf_seed, run_nitf, False, ".ntf", window=2048),
        *[_lens_target(n) for n in LENS_SEEDS],
    ]
}


def corpus_name(target: Target, data: bytes) -> Path:
    """Where an input found by the long run is kept: ``tests/data/fuzz/TARGET/SHA1[:12]SUFFIX``."""
    return CORPUS / target.name / (hashlib.sha1(data).hexdigest()[:12] + target.suffix)


def corpus_files():
    """(target, path) of every kept input."""
    out = []
    if CORPUS.is_dir():
        for d in sorted(CORPUS.iterdir()):
            if d.is_dir() and d.name in TARGETS:
                out += [(TARGETS[d.name], p) for p in sorted(d.iterdir()) if p.is_file()]
    return out


def keep(target: Target, data: bytes) -> Path:
    """Keep ``data`` in the corpus (idempotent)."""
    p = corpus_name(target, data)
    p.parent.mkdir(parents=True, exist_ok=True)
    if not p.exists():
        p.write_bytes(data)
    return p


__all__ = ["TARGETS", "Target", "Finding", "check_error", "expect_clear", "corpus_files", "keep", "os"]
