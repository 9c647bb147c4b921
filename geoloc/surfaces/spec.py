"""A surface as plain values: what :func:`geoloc.cli._options.surface_from_args` reads from
the shared options, which a Dask campaign sends to its workers (docs/architecture.md,
"The `Surface` interface").

:meth:`SurfaceSpec.build` is the one way from a DEM's name to a
:class:`~geoloc.surfaces.base.Surface`: it opens the DEM with
:func:`geoloc.surfaces.mosaic.open_dem_or_mosaic` (one raster, or a folder, ``.vrt`` or
list of tiles: a mosaic) and makes the "DEM or height" choice with
:func:`geoloc.surfaces.terrain.surface_for`. Every verb and every campaign unit builds
its surface through it, so a workflow never opens a DEM itself.
Degrees and metres (docs/conventions.md).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np
from numpy.typing import ArrayLike

from geoloc.surfaces.base import is_mosaic

if TYPE_CHECKING:
    from geoloc.surfaces.base import Surface
    from geoloc.surfaces.dem import DEM


@dataclass(frozen=True)
class SurfaceSpec:
    """What a surface is made of, by value (hashable and picklable: a campaign's workers get it).

    Attributes
    ----------
    dem : path-like, sequence of path-like, or None
        ``--dem``: one raster, a folder of tiles, a ``.vrt``, or several rasters (one mosaic).
        Once made, the spec holds one path as a ``str`` and several as a tuple of ``str`` (a
        sequence of one path is that path), so that it is hashable.
    dem_datum : {"egm96", "ellipsoid"}
        Vertical datum of the DEM's heights.
    method, dem_model : str
        The DEM solver (:func:`geoloc.surfaces.terrain.intersect_dem`).
    eps_h, threshold : float or None
        The solver's tolerances [m]; None: the method's own default.
    cache_bytes : int or None
        A mosaic's tile cache bound [bytes]; None: the mosaic's default.
    target_h_m : float or None
        Without a DEM: one ellipsoidal target height [m] for every ray ...
    height_column : str or None
        ... or the column of the records holding one per record (``build(heights=...)``).
    kind : {"inflated", "geodetic"}
        The height surface's kind (:class:`geoloc.surfaces.height.HeightSurface`).
    """

    dem: str | os.PathLike[str] | Sequence[str | os.PathLike[str]] | None = None
    dem_datum: str = "egm96"
    method: str = "exact"
    dem_model: str = "bilinear"
    eps_h: float | None = None
    threshold: float | None = None
    cache_bytes: int | None = None
    target_h_m: float | None = None
    height_column: str | None = None
    kind: str = "inflated"

    def __post_init__(self):
        d = self.dem
        if isinstance(d, (list, tuple)):
            names = tuple(str(x) for x in d)
            d = names[0] if len(names) == 1 else names
        elif d is not None:
            d = str(d)
        object.__setattr__(self, "dem", d)  # one path, or a tuple of them: hashable
        if self.target_h_m is not None:
            object.__setattr__(self, "target_h_m", float(self.target_h_m))

    def _dem_names(self) -> str | tuple[str, ...] | None:
        """``dem`` as :meth:`__post_init__` holds it: one path, a tuple of them, or None."""
        return cast("str | tuple[str, ...] | None", self.dem)

    @property
    def solver_options(self) -> dict:
        """The tolerances that were given (``eps_h``, ``threshold``)."""
        return {k: v for k, v in (("eps_h", self.eps_h), ("threshold", self.threshold)) if v is not None}

    def raster(self, what: str = "--dem") -> DEM | None:
        """The one DEM raster the spec names (a :class:`~geoloc.surfaces.dem.DEM`), opened by
        :meth:`build`; None without a DEM. For a consumer that draws or samples one raster (the
        rerun recordings' mesh and solver trace): a mosaic (a folder, a ``.vrt``, several
        files) is a ValueError naming ``what`` and the path."""
        from geoloc.surfaces.base import terrain_of

        dem = self._dem_names()
        if dem is None:
            return None
        if isinstance(dem, tuple) or Path(dem).is_dir() or dem.lower().endswith(".vrt"):
            shown = ", ".join(dem) if isinstance(dem, tuple) else dem
            raise ValueError(f"{what} {shown} is a mosaic: this reads one DEM raster, not a mosaic")
        from geoloc.surfaces.dem import DEM

        raster = terrain_of(self.build())
        assert raster is None or isinstance(raster, DEM)  # one raster file: a mosaic was refused above
        return raster

    def build(self, heights: ArrayLike | None = None, *, whole: bool = False) -> Surface:
        """The :class:`~geoloc.surfaces.base.Surface`: the DEM if one is named, else the heights.

        Parameters
        ----------
        heights : array_like, optional
            With ``height_column``: the records' target heights, one per record [m, ellipsoidal]
            (a :class:`~geoloc.surfaces.height.PerRecordHeightSurface`).
        whole : bool
            A mosaic read once as one in-memory DEM (its :meth:`~geoloc.surfaces.mosaic.DemMosaic.to_dem`):
            for inputs whose rays spread over the whole area a packet or photo at a time.

        Raises
        ------
        ValueError
            Neither a DEM nor a height; or ``height_column`` without its ``heights``.
        FileNotFoundError, ValueError
            From the DEM's opener, naming the file.
        """
        from geoloc.surfaces.terrain import surface_for

        names = self._dem_names()
        if names is not None:
            from geoloc.surfaces.mosaic import open_dem_or_mosaic  # a start-up cost a height does not need

            mosaic = {} if self.cache_bytes is None else {"cache_bytes": int(self.cache_bytes)}
            source = list(names) if isinstance(names, tuple) else Path(names)
            dem = open_dem_or_mosaic(
                source, self.dem_datum, method=self.method, dem_model=self.dem_model, **mosaic, **self.solver_options
            )
            if whole and is_mosaic(dem):
                dem = dem.to_dem()
            return surface_for(dem=dem, method=self.method, dem_model=self.dem_model, **self.solver_options)
        if self.height_column is not None:
            if heights is None:
                raise ValueError(f"height column {self.height_column!r}: no records to read the heights from")
            return surface_for(np.asarray(heights, float), kind=self.kind, per_record=True)
        if self.target_h_m is not None:
            return surface_for(self.target_h_m, kind=self.kind)
        raise ValueError("give a DEM, a height column or a target height (ellipsoidal, metres)")
