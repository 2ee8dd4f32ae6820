"""The camera file: a camera model, its image size, the scope's light rig and the sensor's response, as JSON.

What ``simtest render`` writes and ``simtest reconstruct --intrinsics`` reads::

    {"model": "pinhole", "K": [[fx, s, cx], [0, fy, cy], [0, 0, 1]],
     "dist_coeffs": [k1, k2, p1, p2, k3], "image_size": [W, H],
     "lights": [{"position_mm": [x, y, z], "intensity": 1, "falloff": "inverse_square",
                 "profile_exponent": 0}]}

- ``"model"``: ``"pinhole"`` (default; ``"K"``, optional ``"dist_coeffs"``), ``"fisheye"`` (``"K"``, ``"D"``)
  or ``"omnidirectional"`` (``"cx"``, ``"cy"``, ``"a0"`` .. ``"a4"``, ``"c"``, ``"d"``, ``"e"``);
  :mod:`simtest.geometry.cameras`.
- ``"image_size"``: [W, H] in pixels (optional; null allowed).
- ``"lights"``: optional, camera frame (:mod:`simtest.geometry.lights`); absent: one light at the camera
  centre; null is an error (a rig meant but lost). Checked by :func:`~simtest.geometry.lights.check_scope_rig`.
- ``"response"``: optional (:mod:`simtest.geometry.response`); absent means linear.

Unknown keys and booleans where numbers belong are errors; every error is one line naming the file and the
key. OpenCV YAML/XML files (``cv2.FileStorage``) are read as pinholes from ``camera_matrix`` (or ``K``),
``dist_coeffs`` (or ``distortion_coefficients``) and ``image_width``/``image_height``; other keys are ignored.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from simtest._io import atomic_write_json
from simtest.geometry.camera import IntrinsicsError, validate_intrinsics
from simtest.geometry.cameras import CameraModel, FisheyeCamera, OmnidirectionalCamera, PinholeCamera
from simtest.geometry.lights import Light, LightRig, LightRigError, check_scope_rig
from simtest.geometry.response import ResponseError, SensorResponse

__all__ = ["CameraFile", "CameraFileError", "camera_from_dict", "load_camera", "save_camera", "save_intrinsics"]

_MODEL_KEYS = {"pinhole": {"required": ("K",), "optional": ("dist_coeffs",)},
               "fisheye": {"required": ("K", "D"), "optional": ()},
               "omnidirectional": {"required": ("cx", "cy", "a0", "a1", "a2", "a3", "a4", "c", "d", "e"),
                                   "optional": ()}}
_COMMON_KEYS = ("model", "image_size", "lights", "response")
_LIGHT_KEYS = ("position_mm", "intensity", "falloff", "profile_exponent")


class CameraFileError(IntrinsicsError):
    """A camera file is unusable; the one-line message names the file and the key."""


@dataclass(frozen=True)
class CameraFile:
    """What a camera file holds.

    Attributes
    ----------
    model : CameraModel
        The camera model (with its image size when the file gives one).
    lights : LightRig
        The light rig; :meth:`LightRig.colocated` when the file has no ``"lights"``.
    response : SensorResponse or None
        The sensor's response (``"response"``); None when the file has none (linear).
    """

    model: CameraModel
    lights: LightRig
    response: SensorResponse | None = None


def _has_bool(value) -> bool:
    return isinstance(value, bool) or (isinstance(value, (list, tuple)) and any(_has_bool(v) for v in value))


def camera_from_dict(data: dict, where: str = "camera") -> CameraModel:
    """A camera model from its camera-file JSON object (the ``"lights"`` key is ignored here).

    Parameters
    ----------
    data : dict
        As :meth:`CameraModel.to_json_dict` writes it.
    where : str
        What to name in error messages.

    Returns
    -------
    CameraModel

    Raises
    ------
    CameraFileError
        As :func:`load_camera`.
    """
    if not isinstance(data, dict):
        raise CameraFileError(f"{where}: must be a JSON object with a 'model' and its parameters")
    name = data.get("model", "pinhole")
    if name not in _MODEL_KEYS:
        raise CameraFileError(f"{where}: key 'model' must be one of {sorted(_MODEL_KEYS)}, got {name!r}")
    keys = _MODEL_KEYS[name]
    allowed = set(_COMMON_KEYS) | set(keys["required"]) | set(keys["optional"])
    missing = [k for k in keys["required"] if k not in data]
    if missing:
        raise CameraFileError(f"{where}: missing key '{missing[0]}' for model '{name}'")
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise CameraFileError(f"{where}: unknown key '{unknown[0]}' for model '{name}' "
                              f"(allowed: {', '.join(sorted(allowed))})")
    for k in (*keys["required"], *keys["optional"], "image_size"):
        if k in data and _has_bool(data[k]):
            raise CameraFileError(f"{where}: key '{k}' must hold numbers, got a boolean in {data[k]!r}")
    size = data.get("image_size")
    if size is not None and not (isinstance(size, list) and len(size) == 2
                                 and all(isinstance(s, int) and s > 0 for s in size)):
        raise CameraFileError(f"{where}: key 'image_size' must be [W, H] positive integers, got {size!r}")
    try:
        if name == "omnidirectional":
            return OmnidirectionalCamera(data["cx"], data["cy"], [data[f"a{i}"] for i in range(5)], data["c"],
                                         data["d"], data["e"], size)
        K = validate_intrinsics(data["K"], where=f"{where}: key 'K'")
        if name == "pinhole":
            return PinholeCamera(K, data.get("dist_coeffs"), size)
        return FisheyeCamera(K, data["D"], size)
    except CameraFileError:
        raise
    except IntrinsicsError as exc:
        msg = str(exc)
        if msg.startswith(where):
            raise CameraFileError(msg) from None
        key, _, rest = msg.partition(": ")
        raise CameraFileError(f"{where}: key '{key}': {rest}") from None


def _lights_from_list(value, where: str) -> LightRig:
    if value is None:
        raise CameraFileError(f"{where}: key 'lights' is null; give a list of lights, or leave the key out "
                              f"for one light at the camera centre")
    if not isinstance(value, list):
        raise CameraFileError(f"{where}: key 'lights' must be a list of lights, got {value!r}")
    lights = []
    for i, item in enumerate(value):
        at = f"{where}: lights[{i}]"
        if not isinstance(item, dict):
            raise CameraFileError(f"{at}: must be an object with 'position_mm', got {item!r}")
        unknown = sorted(set(item) - set(_LIGHT_KEYS))
        if unknown:
            raise CameraFileError(f"{at}: unknown key '{unknown[0]}' (allowed: {', '.join(_LIGHT_KEYS)})")
        if "position_mm" not in item:
            raise CameraFileError(f"{at}: missing key 'position_mm'")
        try:
            lights.append(Light(**item))
        except LightRigError as exc:
            raise CameraFileError(f"{at}.{exc}") from None
    try:
        return check_scope_rig(LightRig(tuple(lights)))
    except LightRigError as exc:
        raise CameraFileError(f"{where}: {exc}") from None


def _load_opencv(path: Path) -> CameraModel:
    """A pinhole from an OpenCV YAML/XML file; every OpenCV failure becomes one line."""
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:
        raise CameraFileError(f"{path}: not a readable OpenCV YAML/XML file ({_first_line(exc)})") from None
    if not fs.isOpened():
        raise CameraFileError(f"{path}: not a readable OpenCV YAML/XML file")
    try:
        root = fs.root()
        if not root.isMap():
            raise CameraFileError(f"{path}: not an OpenCV YAML/XML map of keys")
        key = next((k for k in ("camera_matrix", "K") if not fs.getNode(k).empty()), None)
        if key is None:
            raise CameraFileError(f"{path}: missing key 'camera_matrix'")
        K = validate_intrinsics(_read_mat(fs, key, path), where=f"{path}: key '{key}'")
        dkey = next((k for k in ("dist_coeffs", "distortion_coefficients") if not fs.getNode(k).empty()), None)
        dist = _read_mat(fs, dkey, path) if dkey else None
        size = None
        w, h = fs.getNode("image_width"), fs.getNode("image_height")
        if not w.empty() or not h.empty():
            for k, node in (("image_width", w), ("image_height", h)):
                if not node.isInt() or int(node.real()) <= 0:
                    raise CameraFileError(f"{path}: key '{k}' must be a positive integer")
            size = (int(w.real()), int(h.real()))
        try:
            return PinholeCamera(K, dist, size)
        except IntrinsicsError as exc:
            raise CameraFileError(f"{path}: key '{dkey}': {exc}") from None
    except (cv2.error, SystemError) as exc:
        raise CameraFileError(f"{path}: malformed OpenCV YAML/XML ({_first_line(exc)})") from None
    finally:
        fs.release()


def _read_mat(fs, key: str, path: Path) -> np.ndarray:
    node = fs.getNode(key)
    if not (node.isMap() or node.isSeq()):
        raise CameraFileError(f"{path}: key '{key}' must be an OpenCV matrix")
    try:
        m = node.mat()
    except (cv2.error, SystemError) as exc:
        raise CameraFileError(f"{path}: key '{key}' is not a well-formed OpenCV matrix ({_first_line(exc)})") from None
    if m is None:
        raise CameraFileError(f"{path}: key '{key}' is not a well-formed OpenCV matrix")
    return m


def _first_line(exc: BaseException) -> str:
    """OpenCV's own reason, one line (a SystemError from cv2's bindings wraps the cv2.error)."""
    if isinstance(exc, SystemError) and exc.__cause__ is not None:
        exc = exc.__cause__
    text = str(exc).strip()
    for line in text.splitlines():
        if "error:" in line:
            return line.split("error:", 1)[1].strip()
    return text.splitlines()[0] if text else type(exc).__name__


def load_camera(path) -> CameraFile:
    """Read a camera file (JSON, or an OpenCV ``.yml``/``.yaml``/``.xml`` pinhole calibration).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    CameraFile

    Raises
    ------
    CameraFileError
        Missing or unreadable file, malformed JSON or YAML, an unknown or missing key, a boolean where a
        number belongs, or invalid parameters; one line naming the file and the key.
    """
    path = Path(path)
    if not path.is_file():
        raise CameraFileError(f"{path}: camera file not found")
    if path.suffix.lower() in (".yml", ".yaml", ".xml"):
        return CameraFile(model=_load_opencv(path), lights=LightRig.colocated())
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CameraFileError(f"{path}: not valid JSON ({exc})") from None
    model = camera_from_dict(data, str(path))
    lights = _lights_from_list(data["lights"], str(path)) if "lights" in data else LightRig.colocated()
    response = None
    if "response" in data:
        try:
            response = SensorResponse.from_json(data["response"], f"{path}: response")
        except ResponseError as exc:
            raise CameraFileError(str(exc)) from None
    return CameraFile(model=model, lights=lights, response=response)


def save_camera(path, model: CameraModel, lights: LightRig | None = None,
                response: SensorResponse | None = None) -> Path:
    """Write a camera file (module docstring format), atomically.

    Parameters
    ----------
    path : str or Path
        Destination ``.json``.
    model : CameraModel
        The camera.
    lights : LightRig or None
        Written as ``"lights"`` when given; None leaves the key out (one co-located light).
    response : SensorResponse or None
        Written as ``"response"`` when given; None leaves the key out (linear).

    Returns
    -------
    Path
        The written path.
    """
    if not isinstance(model, CameraModel):
        raise TypeError(f"save_camera needs a CameraModel, got {type(model).__name__}")
    d = model.to_json_dict()
    if lights is not None:
        d["lights"] = lights.to_json_list()
    if response is not None:
        d["response"] = response.to_json()
    return atomic_write_json(path, d, indent=2)


def save_intrinsics(path, K, dist_coeffs=None, image_size=None) -> Path:
    """Write a pinhole camera file (:func:`save_camera` of a :class:`PinholeCamera`).

    Parameters
    ----------
    path : str or Path
        Destination ``.json``.
    K : array_like of shape (3, 3)
        Intrinsics, validated.
    dist_coeffs : array_like or None
        OpenCV distortion coefficients.
    image_size : (W, H) or None
        Image size in pixels.

    Returns
    -------
    Path
    """
    size = None if image_size is None else (int(image_size[0]), int(image_size[1]))
    return save_camera(path, PinholeCamera(K, dist_coeffs, size))
