"""MISB ST 0601 KLV decoding speed: geoloc.io.klv against klvdata, in the same run.

Encodes 100 000 UAS Datalink LS packets carrying every item geoloc.io.klv decodes
(time stamp, texts, platform attitude, sensor position and pointing, slant range,
frame centre, offset and full corners, target location and error, heights; ~300
bytes each, values varying packet to packet), then times decoding them:

- ours: ``list(iter_packets(data))``, one Packet (a dict of fields) per packet,
  checksums verified;
- ours, vectorised: ``packets_to_columns(data)``, numpy columns, checksums verified;
- klvdata: ``StreamParser(data)`` and ``MetadataList()`` of each packet (it does not
  verify checksums). klvdata is much slower, so it decodes the first
  ``--klvdata-packets`` packets (default 10 000; ``--klvdata-packets 100000`` for all).

Each figure is the median of ``--repeat`` runs (default 5; 3 for klvdata), wall time
(time.perf_counter) and CPU time (time.process_time). Prints packets per second and
``ratio: X`` = ours / klvdata (packets per second, wall time).

Run: python benchmarks/bench_klv.py [--packets N] [--repeat R] [--klvdata-packets M]
"""

import argparse
import time

import numpy as np

from geoloc.io.klv import TAGS, Packet, encode_packet, iter_packets, packets_to_columns

from _timing import timed  # benchmarks/_timing.py (the script's folder is on sys.path)


def make_packets(n, seed=0):
    rng = np.random.default_rng(seed)
    cols = {}
    for s in TAGS:
        if s.kind in ("uint", "int"):
            cols[s.name] = rng.uniform(s.lo, s.hi, n).tolist()
    names = list(cols)
    t0 = 1_700_000_000_000_000
    blobs = []
    for i in range(n):
        f = {name: cols[name][i] for name in names}
        f["precision_time_stamp_us"] = t0 + 33_367 * i
        f["mission_id"] = "MISSION01"
        f["platform_tail_number"] = "AF-101"
        f["platform_designation"] = "MQ1-B"
        f["image_source_sensor"] = "EO"
        f["image_coordinate_system"] = "WGS-84"
        f["uas_ls_version"] = 17
        blobs.append(encode_packet(f))
    return blobs


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--packets", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--klvdata-packets", type=int, default=10_000)
    ap.add_argument("--klvdata-repeat", type=int, default=3)
    args = ap.parse_args()

    t = time.perf_counter()
    blobs = make_packets(args.packets)
    t_enc = time.perf_counter() - t
    data = b"".join(blobs)
    n = len(blobs)
    print(
        f"packets: {n}, {len(data) / n:.0f} bytes each, {len(data) / 1e6:.1f} MB "
        f"(encoded in {t_enc:.2f} s, {n / t_enc:,.0f} packets/s)"
    )

    w, c, res = timed(lambda: list(iter_packets(data)), args.repeat)
    assert len(res) == n and all(isinstance(r, Packet) for r in res)
    ours = n / w
    print(
        f"ours (iter_packets, dict per packet):   wall {w * 1e3:8.1f} ms  cpu {c * 1e3:8.1f} ms  "
        f"{ours:12,.0f} packets/s"
    )
    w, c, cols = timed(lambda: packets_to_columns(data), args.repeat)
    assert len(cols["offset"]) == n
    vec = n / w
    print(
        f"ours (packets_to_columns, vectorised):  wall {w * 1e3:8.1f} ms  cpu {c * 1e3:8.1f} ms  {vec:12,.0f} packets/s"
    )

    import klvdata

    m = min(args.klvdata_packets, n)
    sub = b"".join(blobs[:m])

    def klvdata_decode():
        return [p.MetadataList() for p in klvdata.StreamParser(sub)]

    w, c, kd = timed(klvdata_decode, args.klvdata_repeat)
    assert len(kd) == m
    # Same values (first packet, a latitude): the two decoders agree.
    assert abs(float(kd[0][13][3]) - res[0]["sensor_latitude_deg"]) < 1e-9
    theirs = m / w
    print(
        f"klvdata (StreamParser + MetadataList):  wall {w * 1e3:8.1f} ms  cpu {c * 1e3:8.1f} ms  "
        f"{theirs:12,.0f} packets/s  ({m} packets)"
    )
    print(f"vectorised / klvdata: {vec / theirs:.1f}")
    print(f"ratio: {ours / theirs:.1f}")


if __name__ == "__main__":
    main()
