"""What every layer of the viewer shares: a call that cannot take the session down.

A layer (``docs/architecture.md``, "The viewer: sessions and layers") runs its callbacks from
the GUI's and the session's hooks; an exception there would end the viewer for every tab.
:func:`call_safely` runs the call, prints a bug's traceback on stderr (named by the layer) and
returns None, so the session goes on.
"""

from __future__ import annotations

import sys
import traceback


def call_safely(fn, *args, what: str = "", lock=None):
    """``fn(*args)``, under ``lock`` when given; an exception is printed on stderr (with ``what``,
    the layer's name, when given) and None returned."""
    try:
        if lock is None:
            return fn(*args)
        with lock:
            return fn(*args)
    except Exception:  # a layer's bug must not take the viewer down: report it, keep going
        if what:
            print(f"geoloc view: error in {what}:", file=sys.stderr)
        traceback.print_exc(file=sys.stderr)
        return None


def own_update(owner, event=None) -> bool:
    """True for a GUI update the server made itself while ``owner`` muted its callbacks
    (``owner._mute``: the server sets a handle's value and viser calls the handle's callbacks
    with ``event.client`` None, in the setting thread).

    A person's update (``event.client`` set) is never muted: it runs in viser's thread and may
    arrive while another thread (a live tab growing its timeline) holds the mute for its own
    sets. Muting it lost the person's move: the slider showed frame 3, the view stayed on 107
    (``tests/viz/test_live_view.py``; ``tests/viz/test_viz_mute.py``)."""
    return bool(getattr(owner, "_mute", False)) and getattr(event, "client", None) is None
