"""One ``load_scenario`` for every scenario file geoloc reads.

A scenario file is a TOML whose top-level ``kind`` says what it describes; the
loader of that kind validates it (errors name the file, the table, the key and
the value) and returns its typed object:

=============== ========================================================== =====================================
kind            what                                                       returns
=============== ========================================================== =====================================
``montecarlo``  an error budget at a nominal pose [Q17 section 3]          :class:`geoloc.analysis.errormodel.ErrorModel`
``flight_scan`` a simulated flight with a whisk-broom scan (``geoloc log``) :class:`geoloc.workflows.flight.FlightScenario`
``limb``        a limb-viewing orbit and slit [L18]                        :class:`geoloc.workflows.limb_scenario.LimbScenario`
``pushbroom``   a pushbroom camera to fit an RPC to [L12]                  :class:`geoloc.workflows.rpc_scenario.RPCScenario`
``frame``       a frame camera at one pose to fit an RPC to                :class:`geoloc.workflows.rpc_scenario.RPCScenario`
=============== ========================================================== =====================================

Files written before ``kind`` existed still load: the kind is then recognised
from the tables the file has (``[orbit]`` + ``[sensor]``: limb; ``[nominal]`` +
``[errors]``: montecarlo; ``[aircraft]`` + ``[scan]``: flight_scan). A verb
that needs one kind says so when given another (``expect=``), instead of
failing on the first key it does not know.

The viewer's scene (a records file, a record, a sensor and a DEM) is not a
scenario file; it is built by ``geoloc_viz.scenario.load_view_scenario``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Literal, overload

from geoloc.tomlio import read_toml

if TYPE_CHECKING:
    from geoloc.analysis.errormodel import ErrorModel
    from geoloc.workflows.flight import FlightScenario
    from geoloc.workflows.limb_scenario import LimbScenario
    from geoloc.workflows.rpc_scenario import RPCScenario

    #: What :func:`load_scenario` returns: the object of the file's kind.
    Scenario = ErrorModel | FlightScenario | LimbScenario | RPCScenario

#: Every kind, with what it is (for messages).
KINDS = {
    "montecarlo": "a Monte Carlo error budget (geoloc montecarlo)",
    "flight_scan": "a simulated flight with a scan (geoloc log)",
    "limb": "a limb-viewing orbit (geoloc limb, geoloc view --scenario)",
    "pushbroom": "a pushbroom camera for an RPC fit (geoloc rpc)",
    "frame": "a frame camera for an RPC fit (geoloc rpc)",
}


def scenario_kind(data: dict, source: str = "scenario") -> str:
    """The ``kind`` of a parsed scenario file: the key itself, else recognised from its tables."""
    kind = data.get("kind")
    if kind is not None:
        if not isinstance(kind, str) or kind not in KINDS:  # kind = [] raised "unhashable type" (fuzzing)
            raise ValueError(f"{source}: kind = {kind!r} is not a scenario kind; known: {sorted(KINDS)}")
        return kind
    tables = {k for k, v in data.items() if isinstance(v, dict)}
    if {"orbit", "sensor"} <= tables:
        return "limb"
    if {"nominal", "errors"} <= tables:
        return "montecarlo"
    if {"aircraft", "scan"} <= tables:
        return "flight_scan"
    raise ValueError(
        f"{source}: no 'kind' key, and its tables {sorted(tables)} are not those of a known "
        f"scenario; set kind = one of {sorted(KINDS)}"
    )


@overload
def load_scenario(path: str | os.PathLike[str], expect: Literal["montecarlo"]) -> ErrorModel: ...


@overload
def load_scenario(path: str | os.PathLike[str], expect: Literal["flight_scan"]) -> FlightScenario: ...


@overload
def load_scenario(path: str | os.PathLike[str], expect: Literal["limb"]) -> LimbScenario: ...


@overload
def load_scenario(
    path: str | os.PathLike[str],
    expect: Literal["pushbroom", "frame"] | tuple[Literal["pushbroom", "frame"], ...],
) -> RPCScenario: ...


@overload
def load_scenario(path: str | os.PathLike[str], expect: str | Sequence[str] | None = None) -> Scenario: ...


def load_scenario(path: str | os.PathLike[str], expect: str | Sequence[str] | None = None) -> Scenario:
    """Read any scenario file; return its typed object (the table in the module docstring).

    Parameters
    ----------
    path : str or Path
    expect : str or sequence of str, optional
        Kinds the caller can use; another kind is a ``ValueError`` saying what the
        file is and what was expected.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        Naming the file, key and value when the content is invalid or of another kind.
    """
    path = Path(path)
    data = read_toml(path, "scenario file")
    src = str(path)
    kind = scenario_kind(data, src)
    if expect is not None:
        want = (expect,) if isinstance(expect, str) else tuple(expect)
        if kind not in want:
            raise ValueError(
                f"{src}: this is {KINDS[kind]} (kind = {kind!r}); expected kind {' or '.join(repr(w) for w in want)}"
            )
    body = {k: v for k, v in data.items() if k != "kind"}
    if kind == "montecarlo":
        from geoloc.analysis.errormodel import ErrorModel

        return ErrorModel.from_dict(body, source=src, base_dir=path.parent)
    if kind == "flight_scan":
        from geoloc.workflows.flight import FlightScenario

        return FlightScenario.from_dict(data, base=path.parent, source=src)
    if kind == "limb":
        from geoloc.workflows.limb_scenario import scenario_from_dict

        return scenario_from_dict(body, source=src)
    from geoloc.workflows.rpc_scenario import load_rpc_scenario

    return load_rpc_scenario(path)
