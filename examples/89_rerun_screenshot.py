"""Screenshot a recording in rerun's web viewer, offline, in headless Chromium.

How ``docs/img/rerun_viewer.png`` was made (``docs/rerun.md``)::

    geoloc log flight_scan --out /tmp/scan.rrd --serve &    # Ctrl-C it afterwards
    python examples/89_rerun_screenshot.py 'http://127.0.0.1:9090/?url=rerun%2Bhttp://127.0.0.1:9876/proxy' \\
        docs/img/rerun_viewer.png --at 9

(the picture shows t = 18 s, the recording playing: see ``--at`` below). Given a viewer's page
(``http://...``), the script screenshots it; given an ``.rrd``, it starts ``rerun --serve-web``
on it, where this rerun's web viewer (0.41) draws its heuristic layout, not the recording's
blueprint (``geoloc log --serve`` streams the blueprint as the default: its page shows it).

Given a file, it starts ``rerun --serve-web`` (the viewer's web assets are inside the rerun
wheel: nothing is downloaded; the map view's tiles need a network and stay
blank offline), opens the page in Debian's ``/usr/bin/chromium`` through
playwright (never ``playwright install``), optionally clicks the time box and
types ``--at`` seconds, and takes the screenshot once the page has settled (two
screenshots 5 s apart that agree, after the viewer's panels are up; ``--wait``
is the most it waits). Best effort: under SwiftShader the viewer draws a frame
every few seconds and egui does not always take the typed value as typed (asking
for 9 s gave 1 s here), so look at the picture. The viewer URL's ``#when=TIMELINE@VALUE``
fragment, which rerun documents for moving the time cursor, was tried on this rerun (0.41, a
recording served by ``rerun --serve-web``), outside and inside the encoded ``url`` parameter,
as ``frame@120`` and ``time@9s``: the cursor stayed at the end each time. WebGL runs on SwiftShader: on a
2-core machine the page needs 2-3 minutes to settle. HOME is pointed at a temporary
folder (rerun and Chromium write under ~/.config).
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def settle(page, most_s: float, every_s: float = 5.0, min_s: float = 10.0) -> None:
    """Wait until two screenshots of the page ``every_s`` apart agree (mean change under 0.3 of 255),
    at least ``min_s`` and at most ``most_s`` seconds: the viewer has loaded the recording and drawn it.
    (egui draws on one WebGL canvas that cannot be read back from the page, so the page's pixels are
    compared.)"""
    import io

    import numpy as np
    import PIL.Image

    t0, prev = time.monotonic(), None
    while time.monotonic() - t0 < most_s:
        img = np.asarray(PIL.Image.open(io.BytesIO(page.screenshot(timeout=240_000))).convert("L"), float)
        if prev is not None and time.monotonic() - t0 >= min_s and np.abs(img - prev).mean() < 0.3:
            print(f"settled after {time.monotonic() - t0:.0f} s")
            return
        prev = img
        time.sleep(every_s)
    print(f"not settled after {most_s:.0f} s: look at the picture")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "rrd",
        help="recording to show, or the page of a viewer already serving one (http://..., e.g. "
        "geoloc log ... --serve's http://127.0.0.1:9090/?url=rerun%%2Bhttp://127.0.0.1:9876/proxy)",
    )
    ap.add_argument("png", help="output screenshot")
    ap.add_argument(
        "--at", type=float, default=None, help="time to type into the time box [s], best effort (default: the end)"
    )
    ap.add_argument(
        "--wait", type=float, default=240.0, help="most seconds to wait for the page to settle (default 240)"
    )
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=800)
    a = ap.parse_args()
    from playwright.sync_api import sync_playwright

    home = tempfile.mkdtemp(prefix="geoloc_shot_")
    env = dict(os.environ, HOME=home, XDG_CONFIG_HOME=f"{home}/.config", XDG_DATA_HOME=f"{home}/.local/share")
    web, grpc = free_port(), free_port()
    rerun = shutil.which("rerun") or str(Path(sys.executable).with_name("rerun"))
    page_given = a.rrd.startswith(("http://", "https://"))
    server = (
        None
        if page_given
        else subprocess.Popen(
            [rerun, "--serve-web", "--web-viewer-port", str(web), "--port", str(grpc), a.rrd],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
    )  # its own process group: the wrapper starts the binary
    try:
        if page_given:
            url = a.rrd
        else:
            time.sleep(4)
            url = f"http://127.0.0.1:{web}/?url=rerun%2Bhttp://127.0.0.1:{grpc}/proxy"
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=ARGS, env=env)
            page = browser.new_page(viewport={"width": a.width, "height": a.height})
            page.goto(url, timeout=60_000)
            settle(page, a.wait)
            if a.at is not None:
                # the time box at the right end of the (collapsed) time panel
                page.mouse.click(a.width - 100, a.height - 14, click_count=3)
                time.sleep(3)
                page.keyboard.press("Control+A")
                time.sleep(1)
                page.keyboard.type(f"{a.at:g}")
                page.keyboard.press("Enter")
                settle(page, a.wait)
            page.mouse.move(a.width // 2, 5)  # no hover tooltips in the picture
            settle(page, a.wait)
            page.screenshot(path=a.png, timeout=240_000)
            browser.close()
    finally:
        if server is not None:
            os.killpg(server.pid, signal.SIGTERM)  # the wrapper and the viewer binary it started
            server.wait(timeout=20)
        shutil.rmtree(home, ignore_errors=True)
    print(f"wrote {a.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
