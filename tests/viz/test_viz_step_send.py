"""A timeline step's scene batch leaves the server before its panels' batch is worked out.

viser's sender takes no message while an atomic block is open, and ``flush`` only schedules it: a
panels' batch opened right after the flush held the scene back until the panels were done (in
``benchmarks/bench_frame.py --step-trace 8 --ab``, 4 of 8 steps had their scene reach the page
only with the panels). The oracle is viser's own sender state, read in the browser's connection:
every message pushed before the panels' block opened has been taken for the browser."""

from test_viz_browser import served


def test_a_steps_scene_is_taken_by_the_sender_before_the_panels_block_opens(tmp_path, monkeypatch):
    from test_viz_browser import chromium, open_viewer, wait_for

    from geoloc_viz import flight_layer, flight_model, teaching_panel, uncertainty_layer
    from geoloc_viz.app import GeolocApp

    with served() as server:
        scn = flight_model.default_flight_scenario()
        app = GeolocApp(server, scn, layers=(flight_layer.attach, uncertainty_layer.attach, teaching_panel.attach))
        fl = app.layers[0]
        with chromium(tmp_path) as browser:
            open_viewer(browser, server, 640, 420)
            buf = server._websock_server.get_message_buffer()  # the server session's (broadcast) buffer
            wait_for(lambda: len(buf.generator_cursors) == 1, 40, "the browser's sender")
            seen: list = []
            flush = server.flush
            start = buf.atomic_start

            def record_flush():
                seen.append("flush")
                flush()

            def record_atomic():
                # (the lowest cursor of the browsers' senders, the last message pushed so far)
                seen.append((min(buf.generator_cursors.values()), buf.message_counter - 1))
                start()

            monkeypatch.setattr(server, "flush", record_flush)
            monkeypatch.setattr(buf, "atomic_start", record_atomic)
            for idx in (40, 41, 42):
                seen.clear()
                fl.go(idx)
                cut = seen.index("flush")
                panels = [s for s in seen[cut + 1 :] if s != "flush"]
                assert panels, f"step {idx}: no panels' block after the scene's flush: {seen}"
                taken, pushed = panels[0]
                assert taken >= pushed, (
                    f"step {idx}: the panels' block opened with the sender at message {taken} of {pushed}"
                )
