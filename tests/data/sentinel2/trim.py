"""Make the trimmed copy of Sen2VM's test product TDS1 held in this folder (README.md).

Run once, by hand, from a checkout of github.com/sen2vm/sen2vm-core (commit 3a0fc4d5)::

    python tests/data/sentinel2/trim.py SEN2VM_CHECKOUT tests/data/sentinel2

It keeps detectors 06 and 07 and bands B01, B02, B05: the datastrip metadata without the
elements geoloc does not read (raw attitudes, thermal and health data, packet counters), the
GPS points and attitude quaternions over those detectors' imaging time plus a margin, the
granule metadata of the two detectors, the viewing directions of the two detectors in the
three bands' GIPP files, the spacecraft model, the IERS file, and Sen2VM's reference grids
for them (direct location: testDirectLoc; inverse: testInverseLoc, bands B02 and B05).
Nothing in the kept elements is changed.
"""

from __future__ import annotations

import shutil
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

DETECTORS = ("06", "07")
BANDS = {"B01": 0, "B02": 1, "B05": 4}
INVERSE_BANDS = ("B02", "B05")
MARGIN_S = 4.0
TDS1 = Path("src/test/resources/tests/input/TDS1")
REF = Path("src/test/resources/tests/ref")
GEOID = Path("src/test/resources/DEM_GEOID/S2__OPER_DEM_GEOIDF_MPC__20200112T130120_S20190507T000000.DBL")
#: the geoid crop: whole 15' nodes around the product (its ground lies in 32-34 N, 18-17 W)
GEOID_BOX_DEG = (31.0, 35.0, -20.0, -15.0)  # south, north, west, east


def crop_geoid(src: Path, dst: Path):
    """Sen2VM's geoid (ENVI raw float32, little-endian, 1440 x 721 nodes every 0.25 deg from
    90 N, 180 W: its .HDR's map info puts pixel (1, 1)'s corner at 180.125 W, 90.125 N) cut to
    GEOID_BOX_DEG and written as a GeoTIFF whose pixel centres are the nodes, values unchanged."""
    import rasterio
    from affine import Affine

    a = np.fromfile(src, "<f4").reshape(721, 1440)
    s, n, w, e = GEOID_BOX_DEG
    i0, i1 = int(round((90 - n) / 0.25)), int(round((90 - s) / 0.25))
    j0, j1 = int(round((w + 180) / 0.25)), int(round((e + 180) / 0.25))
    crop = a[i0 : i1 + 1, j0 : j1 + 1]
    dst.parent.mkdir(parents=True, exist_ok=True)
    profile = dict(driver="GTiff", width=crop.shape[1], height=crop.shape[0], count=1, dtype="float32")
    transform = Affine(0.25, 0.0, w - 0.125, 0.0, -0.25, n + 0.125)
    with rasterio.open(dst, "w", crs="EPSG:4326", transform=transform, **profile) as ds:
        ds.write(crop[None])
        ds.update_tags(source=src.name, units="metre", surface="geoid height above the WGS 84 ellipsoid")


def local(tag):
    return tag.split("}", 1)[-1]


def child(el, name):
    for c in el:
        if local(c.tag) == name:
            return c
    return None


def path(el, names):
    for n in names.split("/"):
        el = child(el, n)
        if el is None:
            return None
    return el


def t64(text):
    return np.datetime64(text.strip().rstrip("Z"), "ns")


def trim_datastrip(src: Path, dst: Path):
    ET.register_namespace("n1", "https://psd-15.sentinel2.eo.esa.int/PSD/S2_PDI_Level-1B_Datastrip_Metadata.xsd")
    tree = ET.parse(src)
    root = tree.getroot()
    img = child(root, "Image_Data_Info")
    # the imaging span of the kept detectors (all their lines, every band)
    ts = path(img, "Sensor_Configuration/Time_Stamp")
    times = []
    for bts in ts:
        if local(bts.tag) != "Band_Time_Stamp":
            continue
        for det in list(bts):
            if local(det.tag) == "Detector" and det.get("detectorId") in DETECTORS:
                times.append(t64(child(det, "GPS_TIME").text))
    lo = min(times) - np.timedelta64(int(MARGIN_S * 1e9), "ns")
    hi = max(times) + np.timedelta64(int((22.0 + MARGIN_S) * 1e9), "ns")  # 13824 lines of 1.566 ms
    for name in ("Quality_Indicators_Info",):
        el = child(root, name)
        if el is not None:
            root.remove(el)
    sens = child(img, "Sensor_Configuration")
    for c in list(sens):
        if local(c.tag) not in ("Time_Stamp", "Acquisition_Configuration"):
            sens.remove(c)
    acq = child(sens, "Acquisition_Configuration")
    for c in list(acq):
        if local(c.tag) != "TDI_Configuration_List":
            acq.remove(c)
    for c in list(img):
        if local(c.tag) not in ("Granules_Information", "Sensor_Configuration", "Geometric_Info"):
            img.remove(c)
    dl = path(img, "Granules_Information/Detector_List")
    for det in list(dl):
        if det.get("detectorId") not in DETECTORS:
            dl.remove(det)
    for bts in ts:
        for det in list(bts):
            if local(det.tag) == "Detector" and det.get("detectorId") not in DETECTORS:
                bts.remove(det)
    anc = child(root, "Satellite_Ancillary_Data_Info")
    for c in list(anc):
        if local(c.tag) not in ("Ephemeris", "Attitudes"):
            anc.remove(c)
    eph = child(anc, "Ephemeris")
    for c in list(eph):
        if local(c.tag) not in ("GPS_Points_List", "AOCS_Ephemeris_List"):
            eph.remove(c)
    for lst, keep in ((child(eph, "GPS_Points_List"), ("POSITION_VALUES", "VELOCITY_VALUES", "GPS_TIME")),):
        for pt in list(lst):
            if not lo <= t64(child(pt, "GPS_TIME").text) <= hi:
                lst.remove(pt)
                continue
            for c in list(pt):
                if local(c.tag) not in keep:
                    pt.remove(c)
    aocs = child(eph, "AOCS_Ephemeris_List")
    for pt in list(aocs):
        if not lo <= t64(child(pt, "GPS_TIME").text) <= hi:
            aocs.remove(pt)
    att = child(anc, "Attitudes")
    for c in list(att):
        if local(c.tag) != "Corrected_Attitudes":
            att.remove(c)
    ca = child(att, "Corrected_Attitudes")
    for v in list(ca):
        if not lo <= t64(child(v, "GPS_TIME").text) <= hi:
            ca.remove(v)
            continue
        for c in list(v):
            if local(c.tag) not in ("QUATERNION_VALUES", "QUATERNION_VALIDITY", "GPS_TIME"):
                v.remove(c)
    aux = child(root, "Auxiliary_Data_Info")
    for c in list(aux):
        if local(c.tag) != "IERS_Bulletin":
            aux.remove(c)
    ET.indent(tree, space="  ")
    dst.parent.mkdir(parents=True, exist_ok=True)
    tree.write(dst, encoding="UTF-8", xml_declaration=True)


def trim_viedir(src: Path, dst: Path):
    tree = ET.parse(src)
    for lst in tree.getroot().iter("VIEWING_DIRECTIONS_LIST"):
        for vd in list(lst):
            if vd.get("detector_id") not in DETECTORS:
                lst.remove(vd)
    tree.write(dst, encoding="UTF-8", xml_declaration=True)


def main(repo: Path, out: Path):
    ds = next((repo / TDS1 / "L1B_all/DATASTRIP").glob("*/*MTD_L1B_DS*.xml"))
    trim_datastrip(ds, out / "L1B" / "DATASTRIP" / ds.parent.name / ds.name)
    for det in DETECTORS:
        for g in sorted((repo / TDS1 / "L1B_all/GRANULE").glob(f"*_D{det}_N*/*MTD_L1B_GR*.xml")):
            d = out / "L1B" / "GRANULE" / g.parent.name
            d.mkdir(parents=True, exist_ok=True)
            shutil.copy(g, d / g.name)
            for band in BANDS:
                ref = repo / REF / "testDirectLoc/GRANULE" / g.parent.name / "GEO_DATA"
                for f in ref.glob(f"*_{band}.tif"):
                    (out / "ref/direct" / g.parent.name).mkdir(parents=True, exist_ok=True)
                    shutil.copy(f, out / "ref/direct" / g.parent.name / f.name)
        for band in INVERSE_BANDS:
            for f in (repo / REF / "testInverseLoc").glob(f"*_D{det}_{band}.tif"):
                (out / "ref/inverse").mkdir(parents=True, exist_ok=True)
                shutil.copy(f, out / "ref/inverse" / f.name)
    gipp = out / "L1B" / "GIPP"
    gipp.mkdir(parents=True, exist_ok=True)
    for f in (repo / TDS1 / "inputs/GIPP").iterdir():
        if "SPAMOD" in f.name:
            shutil.copy(f, gipp / f.name)
        elif "VIEDIR" in f.name and any(f.name.endswith(f"_{b}.xml") for b in BANDS):
            trim_viedir(f, gipp / f.name)
    iers = out / "L1B" / "IERS"
    iers.mkdir(parents=True, exist_ok=True)
    for f in (repo / TDS1 / "inputs/IERS").iterdir():
        shutil.copy(f, iers / f.name)
    crop_geoid(repo / GEOID, out / "geoid" / "S2__OPER_DEM_GEOIDF_crop.tif")


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
