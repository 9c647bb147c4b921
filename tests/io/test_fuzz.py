"""Fuzzing of every parser in the suite: a few seconds of hypothesis per parser,
the corpus the long run kept, and memory on a large bad input.

The targets and their promise: tests/fuzz_targets.py. The long run (10 minutes, fixed seed):
``python tools/fuzz.py --minutes 10 --seed 0`` (docs/testing.md, "Fuzzing"). KLV and MPEG-TS
have their own property tests beside these (tests/io/test_klv_wild.py: mutated packets and
streams keep the untouched packets).
"""

from __future__ import annotations

import re
import tracemalloc

import pytest
from hypothesis import HealthCheck, given, settings

import fuzz_targets as F

#: A few seconds per target on this machine (docs/testing.md: the suite's 15-minute goal).
FEW = settings(
    max_examples=25,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


def _given(target):
    @FEW
    @given(target.strategy())
    def run(data):
        import warnings

        with warnings.catch_warnings():  # Pillow's "Truncated File Read" on a mutated photo: its business
            warnings.simplefilter("ignore")
            target.run(data)

    return run


@pytest.mark.parametrize("name", sorted(F.TARGETS))
def test_the_parser_keeps_its_promise_on_mutated_input(name):
    _given(F.TARGETS[name])()


@pytest.mark.parametrize("name", sorted(F.TARGETS))
def test_the_seed_itself_parses_without_an_error(name):
    # the mutations start from a good input: it must load (else every mutation only tests one error)
    t = F.TARGETS[name]
    seen = []
    F.OBSERVER = seen.append
    try:
        t.run(t.seed())
    finally:
        F.OBSERVER = None
    assert seen == [], [str(e) for e in seen]


CORPUS = F.corpus_files()


@pytest.mark.parametrize("target,path", CORPUS, ids=[f"{t.name}/{p.name}" for t, p in CORPUS])
def test_the_corpus_of_the_long_run(target, path):
    # inputs tools/fuzz.py kept: each broke a parser once (fixed since) or reached a distinct clear error
    target.run(path.read_bytes())


def test_the_corpus_is_there():
    names = {t.name for t, _ in CORPUS}
    assert len(CORPUS) >= 20 and len(names) >= 8, sorted(names)


def test_a_check_that_catches_a_bare_error():
    # the judge itself: a KeyError or a message naming nothing is a finding, a clear ValueError is not
    with pytest.raises(F.Finding):
        F.check_error(KeyError("lens"), ["sensor.toml"])
    with pytest.raises(F.Finding):
        F.check_error(ValueError("could not convert string to float: 'x'"))
    with pytest.raises(F.Finding):
        F.check_error(ValueError("fx = 'x' is not a number"), ["sensor.toml"])
    F.check_error(ValueError("sensor.toml: [lens] fx = 'x' is not a number"), ["sensor.toml"])


def test_good_rows_around_a_bad_one_are_kept():
    # the promise of the records target, on one planted bad row: line 5's latitude is text
    seed = F.csv_seed()
    lines = seed.split(b"\n")
    cells = lines[4].split(b",")
    cells[4] = b"north"
    lines[4] = b",".join(cells)
    data = b"\n".join(lines)
    F.run_csv(data)  # would raise Finding if a good row were dropped
    from geoloc.io.records import load_records

    def load(p):
        return load_records(p, angles=("azimuth", "elevation"), columns=F._turret_map())

    r = F._in_file(data, "flight.csv", load)
    n = len([ln for ln in lines[1:] if ln.strip()])
    assert [e.line for e in r.errors] == [5] and len(r.lines) == n - 1
    assert "ac_lat_deg" in str(r.errors[0]) and "north" in str(r.errors[0])


# --------------------------------------------------------------------------- memory stays bounded


def _peak(fn) -> int:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_klv_scan_of_junk_holds_little_memory(tmp_path):
    # 16 MB with no packet in it, read in 1 MB chunks: the scan holds a chunk and the few errors it
    # names, not the file (bound: 4 chunks, for the chunk, its copy, the carry-over and the results)
    import random

    from geoloc.io.klv import read_klv_file

    p = tmp_path / "junk.klv"
    rnd = random.Random(0)
    p.write_bytes(bytes(rnd.getrandbits(8) for _ in range(1 << 16)) * 256)
    peak = _peak(lambda: sum(1 for _ in read_klv_file(p)))
    assert peak < 4 << 20, peak


def test_bad_rows_cost_no_more_memory_than_good_ones(tmp_path):
    # 8 000 rows, all good or all bad (a latitude of text): the bad ones peak no higher than the good
    # ones (10 % for the allocator's noise) and leave one short RowError each (< 1 kB: its line,
    # column, value and reason), not the row
    from geoloc.io.records import load_records

    seed = F.csv_seed().decode().splitlines()
    bad = seed[1].split(",")
    bad[4] = "north"
    n = 8_000
    kept = {}

    def load(kind, row):
        p = tmp_path / f"{kind}.csv"
        p.write_text(seed[0] + "\n" + (row + "\n") * n)

        def go():
            kept[kind] = load_records(p, angles=("azimuth", "elevation"), columns=F._turret_map())
            kept[kind + "_now"] = tracemalloc.get_traced_memory()[0]

        return _peak(go)

    peak_good = load("good", seed[1])
    kept.pop("good")
    peak_bad = load("bad", ",".join(bad))
    assert len(kept["bad"].errors) == n and len(kept["bad"].rows) == 0
    assert peak_bad < 1.1 * peak_good, (peak_bad, peak_good)
    assert kept["bad_now"] < 1000 * n, kept["bad_now"]


# --------------------------------------------------------------------------- the findings, one test each


def test_a_binary_toml_file_is_a_clear_error(tmp_path):
    # found: a sensor or scenario file that is not UTF-8 raised a bare UnicodeDecodeError
    from geoloc.sensors.sensor_file import load_sensor
    from geoloc.workflows.scenario import load_scenario

    p = tmp_path / "sensor.toml"
    p.write_bytes(b"\x80name = 1\n")
    for load in (load_sensor, load_scenario):
        with pytest.raises(ValueError, match=r"sensor\.toml: not valid TOML: byte 0x80 at offset 0 is not UTF-8"):
            load(p)


@pytest.mark.parametrize(
    "line,needle", [("LINE_NUM_COEFF_1: +0.000000000000000d+00", "could not convert"), ("SAMP_OFF: ", "IndexError")]
)
def test_an_rpc_text_value_rasterio_cannot_read_names_the_file(line, needle, tmp_path):
    # found: rasterio's "could not convert string to float" / IndexError (an empty value), naming no file
    import re

    from geoloc.io.rpc_gdal import read_rpc

    key = line.split(":")[0]
    text = re.sub(rf"(?m)^{key}:.*$", line, F.rpc_seed().decode())
    assert text != F.rpc_seed().decode()
    p = tmp_path / "scene_RPC.TXT"
    p.write_text(text)
    with pytest.raises(ValueError, match=r"scene_RPC\.TXT: RPC metadata that cannot be read") as e:
        read_rpc(p, rows=100, cols=100)
    assert needle in str(e.value)


def test_a_truncated_nitf_names_the_file(tmp_path):
    # found: "Cannot read 400040 bytes for NITF header" (a RasterioIOError naming no file)
    from geoloc.io.rpc_gdal import read_rpc

    p = tmp_path / "scene.ntf"
    p.write_bytes(F.nitf_seed()[:300])
    with pytest.raises(ValueError, match=r"scene\.ntf: not a raster GDAL can read"):
        read_rpc(p)


def test_a_lens_file_that_is_binary_or_has_a_nan_size_is_a_clear_error(tmp_path):
    # found: a bare UnicodeDecodeError; and OpenSfM's width NaN: "cannot convert float NaN to integer"
    from geoloc.sensors.lens_io import read_lens_file

    for name in F.LENS_SEEDS:
        p = tmp_path / name
        p.write_bytes(b"\xff" + F.LENS_SEEDS[name])
        with pytest.raises(ValueError, match=rf"{name}: not a text file \(UTF-8\): byte 0xff at offset 0"):
            read_lens_file(p)
    p = tmp_path / "camera_models.json"
    p.write_text('{"c": {"projection_type": "perspective", "width": NaN, "height": 480, "focal": 1.0}}')
    with pytest.raises(ValueError, match=r"camera_models\.json: camera 'c': width = nan: must be a positive integer"):
        read_lens_file(p)


def test_a_pushbroom_scenario_whose_look_angles_fold_names_the_file(tmp_path):
    # found by the long run: "tan_psi_x = [...]: must be strictly monotonic across the detectors",
    # naming no file (the pushbroom sensor's own check)
    import re

    from geoloc.workflows.scenario import load_scenario

    text = F.scenario_seed("zy3_nadir.toml").decode()
    p = tmp_path / "zy3.toml"
    p.write_text(text)
    load_scenario(p)  # the bundled one loads
    # the constant term dropped: the across-track polynomial is then even around the centre, folding
    p.write_text(re.sub(r"(?m)^tan_psi_x_poly = \[0\.0, ", "tan_psi_x_poly = [", text))
    with pytest.raises(ValueError, match=r"zy3\.toml: .*tan_psi_x = .*strictly monotonic"):
        load_scenario(p)


@pytest.mark.parametrize(
    "line,key",
    [('camera = "../cameras/qiao2017.toml"', "camera"), ('dem = "../dem/etopo5_flight_area.tif"', "[terrain] dem")],
)
def test_a_flight_scenario_path_that_is_a_number_is_a_clear_error(line, key, tmp_path):
    # found by the long run: camera = nan raised "unsupported operand type(s) for /: 'PosixPath' and 'float'"
    from geoloc.workflows.scenario import load_scenario

    text = F.scenario_seed("flight_scan.toml").decode()
    assert line in text
    p = tmp_path / "scan.toml"
    p.write_text(text.replace(line, line.split("=")[0] + "= nan"))
    with pytest.raises(ValueError, match=rf"scan\.toml {re.escape(key)} = nan: must be the path of a file"):
        load_scenario(p)


def test_a_stream_pyav_cannot_demultiplex_keeps_the_packets_before():
    # found by the long run (this input is its corpus file): PyAV's demux raised IndexError ("list index
    # out of range") after 19 packets of 20; now a KlvError says where it stopped, the 19 are kept
    from geoloc.io.klv import KlvError, Packet, read_ts_klv

    p = F.CORPUS / "ts" / "4b616d47126a.ts"
    out = list(read_ts_klv(p))
    assert sum(isinstance(r, Packet) for r in out) == 19
    assert isinstance(out[-1], KlvError) and "demultiplexer stopped here (IndexError" in str(out[-1])


def test_a_montecarlo_camera_of_nan_focal_length_names_the_file(tmp_path):
    # found by the long run: "camera field focal_length_px = nan: must be a finite number > 0" named no file
    from geoloc.sensors.sensor_file import load_sensor
    from geoloc.workflows.scenario import load_scenario

    text = F.scenario_seed("qiao2017_table1.toml").decode()
    p = tmp_path / "table1.toml"
    p.write_text(re.sub(r"(?m)^focal_length_px\s*=.*$", "focal_length_px = nan", text, count=1))
    with pytest.raises(ValueError, match=r"table1\.toml \[camera\]: camera field focal_length_px = nan"):
        load_scenario(p)
    cam = tmp_path / "camera.toml"
    cam.write_text(
        re.sub(
            r"(?m)^focal_length_px\s*=.*$",
            "focal_length_px = nan",
            (F.ASSETS / "cameras" / "qiao2017.toml").read_text(),
            count=1,
        )
    )
    with pytest.raises(ValueError, match=r"camera\.toml: camera field focal_length_px = nan"):
        load_sensor(cam)


@pytest.mark.parametrize("name", ["tiangong2_limb.toml", "flight_scan.toml"])
def test_a_scenario_kind_that_is_not_text_is_a_clear_error(name, tmp_path):
    # found by the long run: kind = [] raised "TypeError: unhashable type: 'list'"
    from geoloc.workflows.scenario import load_scenario

    p = tmp_path / name
    p.write_text(re.sub(r'(?m)^kind = ".*"$', "kind = []", F.scenario_seed(name).decode()))
    with pytest.raises(ValueError, match=rf"{re.escape(name)}: kind = \[\] is not a scenario kind"):
        load_scenario(p)


def test_a_photo_whose_header_declares_too_many_pixels_is_a_clear_error():
    # found by the long run (its corpus file): Pillow's DecompressionBombError (no ValueError) escaped
    from geoloc.io.photos import read_photo

    with pytest.raises(ValueError, match=r"41065f07375c\.jpg: its header declares more pixels than Pillow opens"):
        read_photo(F.CORPUS / "photo" / "41065f07375c.jpg")
