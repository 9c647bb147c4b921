"""The flight timeline's play / pause in headless Chromium: pause is immediate.

A person presses play, then pause, and the display must stop where it was: judged on the page
itself. A recorder in the page notes the frame index the panel shows ("frame N of 0 .. M", the summary's)
at the moment the pause button's click event fires there; after the pause the panel must settle
at most two steps later (the step already on its way, and one the server may have sent while the
click travelled) and stay there. Before the player waited for the browser, a software-WebGL page
fell behind a 5 fps timeline and ran on from frame 62 to 85 after pause (as reported);
here the timeline runs at 20 fps, far faster than such a page draws. The player follows the clock
(a step skips the frames the page could not draw in time), so "two steps" are counted in the
sequence of frames the player sent (``FlightLayer.played``); the rate it reaches is measured by
``benchmarks/bench_viewer.py``, not here.
"""

import re
import time

import pytest

from test_viz_browser import ARTIFACTS, chromium, open_viewer, served, wait_for

pytestmark = [pytest.mark.browser]

RECORDER = r"""() => {
  const rx = /frame (\d+) of 0 \.\. \d+/;
  window.__shown = () => { const m = rx.exec(document.body.textContent); return m ? +m[1] : -1; };
  window.__atPause = null;
  document.addEventListener('click', (e) => {
    const b = e.target.closest('button');
    if (b && b.textContent.trim() === 'pause') window.__atPause = window.__shown();
  }, true);
}"""


def test_pause_stops_the_display_where_it_was(tmp_path):
    from geoloc_viz.app import GeolocViewer
    from geoloc_viz.flight_model import default_flight_scenario

    with served() as server:
        viewer = GeolocViewer(server, default_flight_scenario())
        with chromium(tmp_path) as browser:
            page = open_viewer(browser, server, 800, 520)
            cid = next(iter(server.get_clients()))
            wait_for(
                lambda: viewer.session_of(cid) is not None and viewer.session_of(cid).layers, 300, "the tab's session"
            )
            fl = viewer.session_of(cid).layers[0]
            fl.num_fps.value = 20.0
            page.wait_for_selector("text=/frame \\d+ of 0 \\.\\. /", timeout=120000)
            start = fl.current
            page.evaluate(RECORDER)
            # clicks wait up to 3 min: at load 8 on the shared 2-core machine the busy page took 40 s
            page.get_by_role("button", name="play").click(timeout=180000)
            wait_for(lambda: len(fl.played) >= 4, 180, "the timeline to play 4 steps")
            page.get_by_role("button", name="pause").click(timeout=180000)
            wait_for(lambda: not fl._playing, 180, "the pause to reach the server")
            fl._thread.join(60)
            assert not fl._thread.is_alive()
            at_pause = page.evaluate("() => window.__atPause")
            assert at_pause is not None and at_pause > start, at_pause  # the click was seen while playing
            stop = fl.current
            # the page settles on the server's last frame, then stays there
            wait_for(lambda: page.evaluate("() => window.__shown()") == stop, 120, "the page to show the last frame")
            time.sleep(3.0)  # a display that ran on would move on within this (steps are 50 ms apart)
            final = page.evaluate("() => window.__shown()")
            page.screenshot(path=str(ARTIFACTS / "playback_paused.png"))
            print(f"pause: the page showed frame {at_pause} at the click, {final} after it (server {stop})")
            assert final == stop == fl.current
            played = list(fl.played)
            assert at_pause in played and final == played[-1], (at_pause, final, played)
            # the steps the page applied after the click: the one on its way and at most one more
            assert 0 <= len(played) - 1 - played.index(at_pause) <= 2, (at_pause, final, played)
            print(f"playback: {len(played)} steps over {played[-1] - start} frames")
            assert re.search(rf"frame {final} of 0 \.\. ", page.locator("body").inner_text())
