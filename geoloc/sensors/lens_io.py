"""Importers of calibration files: OpenCV, ROS, COLMAP and OpenSfM lenses.

Each reader returns lenses of :mod:`geoloc.sensors.lenses`, in their pixel
convention: (0, 0) is the centre of the top-left pixel, u along the columns,
v along the rows (OpenCV's). What each format means by a pixel, and how it is
converted (``docs/lenses.md``):

- OpenCV FileStorage (YAML/JSON) and ROS ``camera_info``: the same convention
  as here (OpenCV's, which ROS ``image_geometry`` uses): K and the distortion
  coefficients are taken as they are.
- COLMAP ``cameras.txt``: the centre of the top-left pixel is (0.5, 0.5)
  (the top-left *corner* of the image is (0, 0)), so cx = cx_colmap - 0.5,
  cy = cy_colmap - 0.5; focal lengths and distortion are unchanged.
- OpenSfM ``cameras.json``: normalised image coordinates, origin at the image
  centre, x right, y down, scaled by s = max(width, height) (OpenSfM
  documentation, "Geometric Models": pixel = s * normalised + (size - 1) / 2).
  So fx = focal_x * s, cx = (width - 1) / 2 + c_x * s (and the same for y).

Bad files raise ``ValueError`` naming the file, the key or line and the value.
PyYAML parses the YAML files.
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from .lenses import BrownLens, FisheyeLens, Lens, PinholeLens, lens_from_opencv

__all__ = [
    "read_colmap_cameras",
    "read_lens_file",
    "read_opencv_yaml",
    "read_opensfm_cameras",
    "read_ros_camera_info",
]


class _Bad(ValueError):
    """An error of one file: the message is prefixed with the file name."""

    def __init__(self, path, what):
        super().__init__(f"{path}: {what}")


def _text(path) -> str:
    try:
        return Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileNotFoundError(f"lens file not found: {path}") from None
    except UnicodeDecodeError as e:  # else a bare UnicodeDecodeError names no file (found by fuzzing)
        raise _Bad(path, f"not a text file (UTF-8): byte 0x{e.object[e.start]:02x} at offset {e.start}") from None


# --------------------------------------------------------------------------- YAML / JSON parsing
def _yaml_load(path, text):
    """Parse YAML as OpenCV writes it: drop its ``%YAML:1.0`` / ``%YAML 1.2`` directive (PyYAML
    rejects the first and warns on the second) and read ``!!opencv-matrix`` nodes as mappings."""
    import yaml

    class Loader(yaml.SafeLoader):
        pass

    Loader.add_constructor(
        "tag:yaml.org,2002:opencv-matrix", lambda loader, node: loader.construct_mapping(node, deep=True)
    )
    text = re.sub(r"\A\s*%YAML[: ]\s*\d+\.\d+[^\n]*\n", "", text)
    try:
        return yaml.load(text, Loader=Loader)
    except yaml.YAMLError as e:
        raise _Bad(path, f"not valid YAML: {e}") from None


def _json_load(path, text):
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise _Bad(path, f"not valid JSON: {e}") from None


def _mapping(path, data, what):
    if not isinstance(data, dict):
        raise _Bad(path, f"expected a mapping of keys ({what}), got {type(data).__name__}")
    return data


def _number(path, key, value):
    """A float from a number, or a string that is one (PyYAML reads YAML 1.1, where ``1e-5``,
    without a dot, is a string)."""
    if not isinstance(value, bool):
        try:
            return float(value)
        except (TypeError, ValueError):
            pass
    raise _Bad(path, f"{key} = {value!r}: must be a number")


def _integer(path, key, value):
    # NaN and inf first (fuzzing found JSON's NaN raising "cannot convert float NaN to integer")
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or value != int(value)
        or value <= 0
    ):
        raise _Bad(path, f"{key} = {value!r}: must be a positive integer")
    return int(value)


def _matrix(path, key, value, shape=None):
    """A matrix stored as {rows, cols, data} (OpenCV YAML !!opencv-matrix, OpenCV JSON with
    type_id "opencv-matrix", ROS), or as a plain list (of lists)."""
    if isinstance(value, dict):
        if "data" not in value:
            raise _Bad(path, f"{key} = {value!r}: a matrix needs 'data' (and 'rows', 'cols')")
        data = value["data"]
        rows, cols = value.get("rows"), value.get("cols")
    else:
        data, rows, cols = value, None, None
    cells = np.array(data, dtype=object)
    a = np.array([_number(path, key, x) for x in cells.ravel()], dtype=float).reshape(cells.shape)
    if rows is not None and cols is not None:
        rows, cols = _integer(path, f"{key}.rows", rows), _integer(path, f"{key}.cols", cols)
        if a.size != rows * cols:
            raise _Bad(path, f"{key}: rows x cols = {rows} x {cols} but {a.size} data values")
        a = a.reshape(rows, cols)
    if shape is not None:
        if a.size != int(np.prod(shape)):
            raise _Bad(path, f"{key} = {a.tolist()}: expected {shape[0]}x{shape[1]} values")
        a = a.reshape(shape)
    return a


def _first(path, data, keys, required=True):
    """(key, value) of the first of ``keys`` present in ``data``."""
    for key in keys:
        if key in data:
            return key, data[key]
    if required:
        raise _Bad(path, f"missing key: one of {list(keys)} (keys present: {sorted(data)})")
    return None, None


# --------------------------------------------------------------------------- OpenCV FileStorage
_CAMERA_MATRIX_KEYS = ("camera_matrix", "K", "cameraMatrix")
_DIST_KEYS = ("distortion_coefficients", "D", "distCoeffs")
_BROWN_NAMES = ("brown", "plumb_bob", "rational_polynomial", "radtan", "pinhole")
_FISHEYE_NAMES = ("fisheye", "equidistant")


def _image_size(path, data):
    if "image_width" in data or "image_height" in data:
        return tuple(_integer(path, k, data.get(k)) for k in ("image_width", "image_height"))
    key, value = _first(path, data, ("image_size", "imageSize", "width"))
    if key == "width":
        return _integer(path, "width", value), _integer(path, "height", data.get("height"))
    size = _matrix(path, key, value).ravel()
    if size.size != 2:
        raise _Bad(path, f"{key} = {size.tolist()}: must be [width, height]")
    return tuple(_integer(path, key, float(s)) for s in size)


def _model_name(path, key, value) -> str:
    name = str(value).lower()
    if name in _BROWN_NAMES:
        return "brown"
    if name in _FISHEYE_NAMES:
        return "fisheye"
    raise _Bad(
        path,
        f"{key} = {value!r}: not a supported distortion model "
        f"(brown: {list(_BROWN_NAMES)}; fisheye: {list(_FISHEYE_NAMES)})",
    )


def _opencv_lens(path, data, model=None) -> Lens:
    """Lens from a parsed OpenCV FileStorage / ROS mapping."""
    data = _mapping(path, data, "an OpenCV calibration")
    key, K = _first(path, data, _CAMERA_MATRIX_KEYS)
    K = _matrix(path, key, K, (3, 3))
    dkey, D = _first(path, data, _DIST_KEYS, required=False)
    D = np.zeros(0) if D is None else _matrix(path, dkey, D).ravel()
    size = _image_size(path, data)
    file_model = None
    if "distortion_model" in data:
        file_model = _model_name(path, "distortion_model", data["distortion_model"])
    if model is not None and file_model is not None and model != file_model:
        raise _Bad(path, f"distortion_model = {data['distortion_model']!r} contradicts model={model!r}")
    try:
        return lens_from_opencv(K, D, size, model=model or file_model or "brown")
    except ValueError as e:
        raise _Bad(path, f"{key}/{dkey}: {e}") from None


def read_opencv_yaml(path: str | os.PathLike[str], model: str | None = None) -> Lens:
    """Lens from an OpenCV FileStorage file (YAML, or JSON).

    Parameters
    ----------
    path : str or Path
        A file as ``cv2.FileStorage`` writes it: YAML (``%YAML:1.0`` or
        ``%YAML 1.2`` header, matrices tagged ``!!opencv-matrix`` with rows,
        cols, dt, data) or JSON (matrices as objects with ``"type_id":
        "opencv-matrix"``). Keys: the camera matrix ``camera_matrix`` (or
        ``K``, ``cameraMatrix``), the distortion ``distortion_coefficients``
        (or ``D``, ``distCoeffs``; absent means none), the image size
        ``image_width`` and ``image_height`` (or ``image_size`` / ``imageSize``
        = [width, height], or ``width`` and ``height``); optionally
        ``distortion_model`` (plumb_bob, rational_polynomial, radtan, brown,
        pinhole -> Brown; fisheye, equidistant -> fisheye). Other keys are
        ignored. Pixels are OpenCV's, as here: K is taken as it is.
    model : {"brown", "fisheye"}, optional
        The model, if the file does not say; it must agree if the file does.
        Default brown.

    Returns
    -------
    BrownLens or FisheyeLens
    """
    text = _text(path)
    data = _json_load(path, text) if text.lstrip().startswith("{") else _yaml_load(path, text)
    return _opencv_lens(path, data, model)


_ROS_MODELS = {"plumb_bob": "brown", "rational_polynomial": "brown", "equidistant": "fisheye"}


def read_ros_camera_info(path: str | os.PathLike[str]) -> Lens:
    """Lens from a ROS ``camera_info`` YAML file (camera_calibration_parsers).

    Keys used: ``image_width``, ``image_height``, ``camera_matrix`` {rows,
    cols, data}, ``distortion_model`` (plumb_bob: k1, k2, p1, p2, k3;
    rational_polynomial: k1, k2, p1, p2, k3, k4, k5, k6 -> Brown;
    equidistant: k1..k4 -> fisheye), ``distortion_coefficients`` {data}.
    ``rectification_matrix`` and ``projection_matrix`` (stereo rectification)
    are ignored. ROS pixels are OpenCV's (``image_geometry``), as here.
    """
    data = _mapping(path, _yaml_load(path, _text(path)), "a ROS camera_info")
    for key in ("image_width", "image_height", "camera_matrix", "distortion_model", "distortion_coefficients"):
        if key not in data:
            raise _Bad(path, f"missing key {key!r} of a ROS camera_info file")
    name = data["distortion_model"]
    if name not in _ROS_MODELS:
        raise _Bad(path, f"distortion_model = {name!r}: must be one of {list(_ROS_MODELS)}")
    return _opencv_lens(path, data, _ROS_MODELS[name])


# --------------------------------------------------------------------------- COLMAP
# model: (parameter names in COLMAP's order, lens class); "f" is fx = fy, "k" is k1.
_COLMAP_MODELS = {
    "SIMPLE_PINHOLE": (("f", "cx", "cy"), PinholeLens),
    "PINHOLE": (("fx", "fy", "cx", "cy"), PinholeLens),
    "SIMPLE_RADIAL": (("f", "cx", "cy", "k1"), BrownLens),
    "RADIAL": (("f", "cx", "cy", "k1", "k2"), BrownLens),
    "OPENCV": (("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"), BrownLens),
    "FULL_OPENCV": (("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"), BrownLens),
    "OPENCV_FISHEYE": (("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"), FisheyeLens),
}
_COLMAP_PIXEL_OFFSET = 0.5  # COLMAP: the centre of the top-left pixel is (0.5, 0.5)


def read_colmap_cameras(path: str | os.PathLike[str]) -> dict[int, Lens]:
    """Lenses of a COLMAP ``cameras.txt`` (lines ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]``).

    Supported models: SIMPLE_PINHOLE (f, cx, cy), PINHOLE (fx, fy, cx, cy),
    SIMPLE_RADIAL (f, cx, cy, k), RADIAL (f, cx, cy, k1, k2), OPENCV (fx, fy,
    cx, cy, k1, k2, p1, p2), FULL_OPENCV (fx, fy, cx, cy, k1, k2, p1, p2, k3,
    k4, k5, k6), OPENCV_FISHEYE (fx, fy, cx, cy, k1, k2, k3, k4); COLMAP's
    radial and OpenCV models are OpenCV's formulas. The principal point moves
    by half a pixel: cx = cx_colmap - 0.5, cy = cy_colmap - 0.5. Lines
    starting with '#' are comments.

    Returns
    -------
    dict
        camera id (int) -> lens (PinholeLens, BrownLens or FisheyeLens).
    """
    lenses: dict[int, Lens] = {}
    for n, line in enumerate(_text(path).splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        where = f"line {n}"
        fields = line.split()
        if len(fields) < 4:
            raise _Bad(path, f"{where}: {line!r}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]")
        cam_id_text, model, width_text, height_text, *params = fields
        if model not in _COLMAP_MODELS:
            raise _Bad(path, f"{where}: camera model {model!r} is not supported (supported: {list(_COLMAP_MODELS)})")
        names, cls = _COLMAP_MODELS[model]
        if len(params) != len(names):
            raise _Bad(
                path, f"{where}: {model} takes {len(names)} parameters {list(names)}, got {len(params)}: {line!r}"
            )
        try:
            cam_id, width, height = int(cam_id_text), int(width_text), int(height_text)
        except ValueError:
            raise _Bad(
                path,
                f"{where}: CAMERA_ID, WIDTH, HEIGHT = {fields[0]!r}, {fields[2]!r}, {fields[3]!r}: must be integers",
            ) from None
        if cam_id in lenses:
            raise _Bad(path, f"{where}: camera id {cam_id} appears twice")
        values = {name: _number(path, f"{where}: {name}", p) for name, p in zip(names, params)}
        if "f" in values:
            values["fx"] = values["fy"] = values.pop("f")
        values["cx"] -= _COLMAP_PIXEL_OFFSET
        values["cy"] -= _COLMAP_PIXEL_OFFSET
        try:
            lenses[cam_id] = cls(width=width, height=height, **values)
        except ValueError as e:
            raise _Bad(path, f"{where}: {e}") from None
    return lenses


# --------------------------------------------------------------------------- OpenSfM
# projection type: (lens class, focal keys (x, y) or one key, has principal point, coefficients)
_OPENSFM_TYPES = {
    "perspective": (BrownLens, ("focal",), False, ("k1", "k2")),
    "brown": (BrownLens, ("focal_x", "focal_y"), True, ("k1", "k2", "k3", "p1", "p2")),
    "radial": (BrownLens, ("focal_x", "focal_y"), True, ("k1", "k2")),
    "simple_radial": (BrownLens, ("focal_x", "focal_y"), True, ("k1",)),
    "fisheye": (FisheyeLens, ("focal",), False, ("k1", "k2")),
    "fisheye_opencv": (FisheyeLens, ("focal_x", "focal_y"), True, ("k1", "k2", "k3", "k4")),
}


def read_opensfm_cameras(path: str | os.PathLike[str]) -> dict[str, Lens]:
    """Lenses of an OpenSfM ``cameras.json`` (or ``camera_models_overrides.json``).

    Supported projection types (OpenSfM "Geometric Models"; the default, as in
    OpenSfM, is perspective): perspective (focal, k1, k2), brown (focal_x,
    focal_y, c_x, c_y, k1, k2, k3, p1, p2), radial (focal_x, focal_y, c_x,
    c_y, k1, k2), simple_radial (focal_x, focal_y, c_x, c_y, k1) -> BrownLens;
    fisheye (focal, k1, k2), fisheye_opencv (focal_x, focal_y, c_x, c_y,
    k1..k4) -> FisheyeLens. Their formulas are OpenCV's. Missing
    coefficients and principal points are 0, as in OpenSfM; other keys
    (e.g. ``focal_prior``) are ignored.

    OpenSfM's values are in normalised image coordinates (origin at the image
    centre, scale s = max(width, height)):
    fx = focal_x s, fy = focal_y s, cx = (width - 1) / 2 + c_x s,
    cy = (height - 1) / 2 + c_y s.

    Returns
    -------
    dict
        camera name -> lens.
    """
    data = _mapping(path, _json_load(path, _text(path)), "camera name -> camera")
    lenses: dict[str, Lens] = {}
    for name, cam in data.items():
        where = f"camera {name!r}"
        cam = _mapping(path, cam, where)
        ptype = cam.get("projection_type", "perspective")
        if ptype not in _OPENSFM_TYPES:
            raise _Bad(
                path, f"{where}: projection_type = {ptype!r} is not supported (supported: {list(_OPENSFM_TYPES)})"
            )
        cls, focal_keys, has_pp, coeffs = _OPENSFM_TYPES[ptype]
        for key in ("width", "height", *focal_keys):
            if key not in cam:
                raise _Bad(path, f"{where}: missing key {key!r} of a {ptype} camera")
        v = {
            key: _number(path, f"{where}: {key}", cam[key])
            for key in (*focal_keys, *coeffs, "c_x", "c_y")
            if key in cam
        }
        width = _integer(path, f"{where}: width", cam["width"])
        height = _integer(path, f"{where}: height", cam["height"])
        s = float(max(width, height))
        cx, cy = (v.get("c_x", 0.0), v.get("c_y", 0.0)) if has_pp else (0.0, 0.0)
        try:
            lenses[name] = cls(
                fx=v[focal_keys[0]] * s,
                fy=v[focal_keys[-1]] * s,
                cx=(width - 1) / 2.0 + cx * s,
                cy=(height - 1) / 2.0 + cy * s,
                width=width,
                height=height,
                **{k: v.get(k, 0.0) for k in coeffs},
            )
        except ValueError as e:
            raise _Bad(path, f"{where}: {e}") from None
    return lenses


# --------------------------------------------------------------------------- any of them
def read_lens_file(path: str | os.PathLike[str], model: str | None = None, camera: str | int | None = None) -> Lens:
    """One lens from any of the formats above, the reader chosen by extension and content.

    - ``.txt`` -> COLMAP cameras.txt;
    - JSON (``.json``, or text starting with '{'): OpenSfM if its entries have a
      ``projection_type`` or ``focal``/``focal_x``, else OpenCV FileStorage JSON;
    - YAML: ROS camera_info if its ``distortion_model`` is a ROS model and
      ``camera_matrix`` a {rows, cols, data} mapping without the OpenCV tag, else
      OpenCV FileStorage YAML.

    Parameters
    ----------
    path : str or Path
    model : {"brown", "fisheye"}, optional
        Passed to :func:`read_opencv_yaml` (OpenCV files only; the other
        formats state their model).
    camera : optional
        For files with several cameras (COLMAP, OpenSfM): the camera id / name;
        may be omitted if the file has a single camera.
    """
    path = Path(path)
    text = _text(path)
    if path.suffix.lower() == ".txt":
        lenses: dict[Any, Lens] = read_colmap_cameras(path)  # COLMAP ids are numbers
    elif path.suffix.lower() == ".json" or text.lstrip().startswith("{"):
        data = _json_load(path, text)
        is_sfm = (
            isinstance(data, dict)
            and data
            and all(isinstance(c, dict) and ({"projection_type", "focal", "focal_x"} & set(c)) for c in data.values())
        )
        if not is_sfm:
            return _opencv_lens(path, data, model)
        lenses = read_opensfm_cameras(path)
    else:
        if text.lstrip().startswith("%YAML") or "!!opencv-matrix" in text:
            return read_opencv_yaml(path, model)
        data = _yaml_load(path, text)
        if isinstance(data, dict) and data.get("distortion_model") in _ROS_MODELS and model is None:
            return read_ros_camera_info(path)
        return _opencv_lens(path, data, model)
    if model is not None:
        raise _Bad(path, f"model={model!r}: this file states its cameras' models")
    if camera is None:
        if len(lenses) != 1:
            raise _Bad(path, f"{len(lenses)} cameras {list(lenses)}: say which one (camera=...)")
        return next(iter(lenses.values()))
    if camera not in lenses:
        raise _Bad(path, f"camera {camera!r} not in the file (cameras: {list(lenses)})")
    return lenses[camera]
