"""Faults of the machine, each injected: a DEM tile truncated or corrupt in a
mosaic, an input file that changes while it is read. (A full disk, ``/dev/full``, ENOSPC at the
rename and a folder made read-only mid-run are run on every verb's outputs by
tests/cli/test_cli_rules.py.)"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio

from geoloc.cli import main
from geoloc.io.klv import KlvError, Packet, read_klv_file
from geoloc.status import Status
from geoloc.surfaces.dem import DEM
from geoloc.surfaces.mosaic import DemMosaic, DemTileWarning
from geoloc.surfaces.terrain import intersect_dem, random_oblique_rays
from test_mosaic import HIT_TOL_M, SRTM, cut_tiles

ROOT = Path(__file__).resolve().parents[2]


def _damage(path: Path, how: str) -> None:
    data = path.read_bytes()
    if how == "truncated":  # a copy that stopped half way (the IFD, written first by GDAL, is whole)
        path.write_bytes(data[: len(data) // 2])
    else:  # a DEFLATE tile whose second half is garbage: the decoder fails on its strips
        n = len(data)
        path.write_bytes(data[: n // 2] + bytes((7 * i + 13) % 251 for i in range(n - n // 2)))


@pytest.mark.parametrize("how", ["truncated", "corrupt"])
def test_a_damaged_tile_gives_its_rays_nodata_and_the_others_still_run(how, tmp_path):
    tiles, wins = cut_tiles(tmp_path / "t", 2, 0)
    bad = tiles[3]  # tile_11, the south-east quarter
    if how == "corrupt":  # rewrite it compressed, so that garbage is detected (raw Int16 would just read)
        with rasterio.open(bad) as src:
            prof, data = dict(src.profile), src.read(1)
        with rasterio.open(bad, "w", **dict(prof, compress="deflate")) as dst:
            dst.write(data, 1)
    _damage(bad, how)
    merged = DEM.open(SRTM)
    rays = random_oblique_rays(merged, 800, np.random.default_rng(47), inner=0.95)
    with pytest.warns(DemTileWarning, match=r"tile_11\.tif.*cannot be read") as seen:
        m = DemMosaic.open(tmp_path / "t", block=64)
        b = m.intersect(rays)
    assert len([w for w in seen if issubclass(w.category, DemTileWarning)]) == 1  # one line per tile
    a = intersect_dem(rays, merged)
    # the damaged quarter: nodes from row r0 and column c0 on (the linspace cut of the 344 x 403 crop)
    r0, _, c0, _ = wins[3]
    g = merged.grid
    in_bad = (a.lat_deg < g.lat_north_deg - g.dlat_deg * (r0 - 1)) & (
        a.lon_deg > g.lon_west_deg + g.dlon_deg * (c0 - 1)
    )
    assert in_bad.sum() > 50
    # each ray meets the good terrain exactly as on the one raster, or gets a status
    ok = (b.status == Status.OK) & (a.status == Status.OK)
    assert ok.sum() > 300 and np.max(np.abs(a.ecef[ok] - b.ecef[ok])) < HIT_TOL_M
    # (a ray or two that left the one raster meet good terrain on the mosaic: without the damaged
    # quarter's high ground the mosaic's highest node is lower, and the walk starts elsewhere)
    assert ((b.status == Status.OK) & (a.status != Status.OK)).sum() <= 0.01 * len(a.status)
    bad = b.status != Status.OK
    assert set(np.unique(b.status[bad]).tolist()) <= {Status.NODATA, Status.LEFT_DEM}
    assert np.all(np.isnan(b.ecef[bad]))
    assert (b.status[in_bad] == Status.NODATA).mean() > 0.5  # the unreadable half of that tile


def test_replay_on_a_mosaic_with_a_truncated_tile_is_one_warning_and_statuses(tmp_path, capsys):
    import csv

    tiles, _ = cut_tiles(tmp_path / "t", 2, 0)
    records = ROOT / "assets/records/eo_turret_flight.csv"
    first = next(csv.DictReader(records.open()))
    lat, lon = float(first["truth_lat_deg"]), float(first["truth_lon_deg"])

    def holds(p):
        with rasterio.open(p) as src:
            b = src.bounds
        return b.bottom <= lat <= b.top and b.left <= lon <= b.right

    hit = next(p for p in tiles if holds(p))  # the tile under the first record's target
    _damage(hit, "truncated")
    out = tmp_path / "r.csv"
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        rc = main(
            [
                "replay",
                str(records),
                "--sensor",
                str(ROOT / "assets/sensors/eo_turret.toml"),
                "--dem",
                str(tmp_path / "t"),
                "--out",
                str(out),
            ]
        )
    cap = capsys.readouterr()
    err = cap.err
    lines = [ln for ln in err.splitlines() if hit.name in ln]
    assert len(lines) == 1 and lines[0].startswith("geoloc replay: warning: DEM tile "), err
    assert "Traceback" not in err and "DemTileWarning" not in err and rc in (0, 1), err
    rows = list(csv.DictReader(out.open()))
    statuses = [r["status"] for r in rows]
    assert "ok" in statuses and statuses[0] == "nodata"  # the first met the damaged tile; others ran
    # exit 1: some records not located, the summary says which and why
    assert rc == 1 and "not located" in cap.out and "nodata" in cap.out, cap.out


# --------------------------------------------------------------------------- an input that changes as it is read


def _packets(results):
    return [(r.offset, r.fields.get("precision_time_stamp_us")) for r in results if isinstance(r, Packet)]


@pytest.mark.parametrize("change", ["truncated", "appended", "overwritten"])
def test_a_klv_file_that_changes_while_it_is_read(change, tmp_path):
    # read in 4 kB chunks; after the first packet, the file is cut in half, grows, or has its tail
    # overwritten: the read ends without an exception, every packet read before the change point is
    # the one a read of the original gives, and what follows is packets or KlvErrors (never a crash)
    src = (ROOT / "assets/klv/example_flight.klv").read_bytes()
    p = tmp_path / "live.klv"
    p.write_bytes(src)
    whole = list(read_klv_file(p, chunk_size=4096))
    cut = len(src) // 2
    got = []
    for k, r in enumerate(read_klv_file(p, chunk_size=4096)):
        got.append(r)
        if k == 0:
            if change == "truncated":
                with open(p, "r+b") as fh:
                    fh.truncate(cut)
            elif change == "appended":
                with open(p, "ab") as fh:
                    fh.write(src[: len(src) // 3])
            else:
                with open(p, "r+b") as fh:
                    fh.seek(cut)
                    fh.write(bytes(len(src) - cut))
    assert all(isinstance(r, (Packet, KlvError)) for r in got)
    before = [x for x in _packets(whole) if x[0] < cut - 4096]
    assert _packets(got)[: len(before)] == before
    if change == "truncated":
        assert max(o for o, _ in _packets(got)) < cut
