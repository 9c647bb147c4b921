"""The interop section (once the README's, now docs/tour_sensors.md) runs as
written, in an empty folder: the MGRS column, the CoT file opened by takproto (a TAK-style parser),
the NITF RPC read back, ``klv fix`` on the bundled flight; each printed value is the one the page
shows."""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _section():
    text = (ROOT / "docs" / "tour_sensors.md").read_text(encoding="utf-8")
    start = text.index("## MGRS, Cursor-on-Target, NITF RPCs, KLV written back")
    end = text.find("\n## ", start + 10)  # the next section, or the end of the page
    return text[start : end if end >= 0 else len(text)]


def test_docs_interop_section_runs_as_written(tmp_path):
    sec = _section()
    bash = re.search(r"```bash\n(.*?)```", sec, re.S).group(1)
    py = re.search(r"```py\n(.*?)```", sec, re.S).group(1)
    outs = {}
    for line in bash.replace("\\\n", " ").splitlines():  # a command continued with a backslash
        cmd = line.split("#")[0].strip()
        if not cmd or "udp://" in cmd:  # the multicast send is tested on loopback in test_cot.py
            continue
        argv = shlex.split(cmd)
        assert argv[0] == "geoloc", cmd
        r = subprocess.run(
            [sys.executable, "-m", "geoloc", *argv[1:]], cwd=tmp_path, capture_output=True, text=True, timeout=900
        )
        assert r.returncode == 0, (cmd, r.stderr[-2000:])
        outs[cmd] = r.stdout
    # the MGRS column sits after lon_deg, and its first row is the page's
    header, first = (tmp_path / "q17.csv").read_text().splitlines()[:2]
    cols = header.split(",")
    assert cols[cols.index("lon_deg") + 1] == "mgrs"
    want = re.search(r"#   T3,1,\.\.\.,([0-9.]+),([0-9.]+),(\w+),", bash).groups()
    row = dict(zip(cols, first.split(",")))
    assert (row["lat_deg"], row["lon_deg"], row["mgrs"]) == want
    # klv fix: the figures the page quotes
    fix = next(v for k, v in outs.items() if k.startswith("geoloc klv fix"))
    assert "299 packets read, 298 rewritten" in fix, fix
    replay = next(v for k, v in outs.items() if k.startswith("geoloc replay fixed.klv"))
    assert re.search(r"frame-centre error .*max 0\.004 m", replay), replay
    # the Python block: each print is the page's comment on that line
    r = subprocess.run([sys.executable, "-c", py], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    printed = r.stdout.strip().splitlines()
    shown = [line.split("# ")[-1].strip() for line in py.splitlines() if line.startswith("print(")]
    assert len(printed) == len(shown) == 2
    assert printed[0] == shown[0]
    assert abs(float(printed[1]) - float(shown[1])) < 1e-6  # px: the GeoTIFF's and the NITF's RPC agree to 1e-6
