"""Random test cases and checks shared by several test files (exact geometry, seeded)."""

from __future__ import annotations

import numpy as np


def random_circle_pose(seed: int, key: int = 1234):
    """A circle of random radius and pose in front of the camera, its normal facing the camera.

    The centre lies 150 to 400 mm away within +-60 mm laterally, the plane is tilted 0 to 70 deg
    from the viewing ray of the centre (so the image is an ellipse), the radius is 3 to 25 mm.

    Returns
    -------
    centre : ndarray of shape (3,)
    normal : ndarray of shape (3,)
    radius : float
    rng : numpy.random.Generator
        The generator that drew them, for further draws.
    """
    rng = np.random.default_rng(np.random.SeedSequence([key, seed]))
    centre = np.array([rng.uniform(-60, 60), rng.uniform(-60, 60), rng.uniform(150, 400)])
    ray = centre / np.linalg.norm(centre)
    tilt = np.radians(rng.uniform(0, 70))
    perp = np.cross(ray, rng.normal(size=3))
    perp /= np.linalg.norm(perp)
    normal = -np.cos(tilt) * ray + np.sin(tilt) * perp
    return centre, normal, rng.uniform(3, 25), rng


def assert_one_error_line(res, code: int, *words: str) -> None:
    """A command-line result (typer's ``CliRunner``) that failed with ``code`` in one line
    ``error: ...`` holding every one of ``words``, and no traceback."""
    assert res.exit_code == code, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    assert "Traceback" not in res.output
    for w in words:
        assert w in lines[0], lines[0]


def sample_ellipse(ellipse, n: int, *, rng=None, noise_px: float = 0.0) -> np.ndarray:
    """``n`` points (u, v) on an :class:`~simtest.geometry.conics.Ellipse`, evenly spaced in the
    eccentric anomaly from a random phase when ``rng`` is given, plus Gaussian noise of
    ``noise_px`` per coordinate (drawn with ``rng``)."""
    phase = rng.uniform(0, 2 * np.pi) if rng is not None else 0.0
    t = phase + np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    a, b = ellipse.semi_axes
    c, s = np.cos(ellipse.angle_rad), np.sin(ellipse.angle_rad)
    x, y = a * np.cos(t), b * np.sin(t)
    pts = np.stack([ellipse.center[0] + c * x - s * y, ellipse.center[1] + s * x + c * y], axis=1)
    return pts + rng.normal(0.0, noise_px, size=pts.shape) if noise_px > 0 else pts


def frame_pixels(camera, step: float = 1.0) -> np.ndarray:
    """(M, 2) pixel centres on a grid of spacing ``step`` px over a camera model's whole frame
    (``camera.image_size``), its last row and column included."""
    W, H = camera.image_size
    us = np.unique(np.append(np.arange(0.0, W - 1, step), W - 1.0))
    vs = np.unique(np.append(np.arange(0.0, H - 1, step), H - 1.0))
    uu, vv = np.meshgrid(us, vs)
    return np.stack([uu.ravel(), vv.ravel()], axis=1)


def ellipse_to_conic(center_uv, semi_axes, angle_rad: float) -> np.ndarray:
    """Point conic (3, 3) of the ellipse of centre (u, v), semi-axes (a, b) px (``a`` at
    ``angle_rad`` from +u toward +v): ``x^T C x = 0`` on it, negative inside, not normalised
    (Hartley and Zisserman, Multiple View Geometry, sec. 2.2.3)."""
    cx, cy = (float(x) for x in center_uv)
    a, b = (float(x) for x in semi_axes)
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    # (u', v') = R^T (x - centre); u'^2/a^2 + v'^2/b^2 - 1 = 0
    A = c * c / a**2 + s * s / b**2
    B = 2.0 * c * s * (1.0 / a**2 - 1.0 / b**2)
    Cc = s * s / a**2 + c * c / b**2
    D = -2.0 * A * cx - B * cy
    E = -B * cx - 2.0 * Cc * cy
    F = A * cx * cx + B * cx * cy + Cc * cy * cy - 1.0
    return np.array([[A, B / 2, D / 2], [B / 2, Cc, E / 2], [D / 2, E / 2, F]])


def undistort_points(uv, K, dist_coeffs) -> np.ndarray:
    """Pixel points (N, 2) with OpenCV's lens distortion removed under the same K
    (``cv2.undistortPoints`` iterated to convergence); None or zero coefficients: a copy."""
    import cv2

    uv = np.asarray(uv, dtype=np.float64)
    if dist_coeffs is None or not np.any(np.asarray(dist_coeffs, dtype=np.float64)):
        return uv.copy()
    K = np.asarray(K, dtype=np.float64)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    out = cv2.undistortPoints(uv.reshape(-1, 1, 2), K, np.asarray(dist_coeffs, dtype=np.float64).reshape(-1),
                              R=None, P=K, criteria=criteria)
    return out.reshape(-1, 2)


def bench_frame_rows(tmp_path, root: int, index: int, ranges: dict):
    """The sensor-like bench's frame ``index`` drawn at the tuning ``root`` through ``simtest reconstruct`` (its
    camera file, one worker): ``(meta, rows)``, each true highlight's status and angular error (deg; None without
    a light-aware ok normal), scored as the bench scores (:func:`benchmarks.sensor_like.score`)."""
    import json

    from typer.testing import CliRunner

    from benchmarks import sensor_like
    from simtest.cli import app

    frame, camera, normal, truth, meta = sensor_like.drawn_frame(root, index, ranges)
    path = sensor_like.write_frame(tmp_path, frame, camera, meta)
    res = CliRunner().invoke(app, ["reconstruct", str(path), "-k", str(tmp_path / "camera.json"),
                                   "-o", str(tmp_path / "out"), "--no-overlay", "-j", "1"])
    assert res.exit_code == 0, res.output
    specs = json.loads((tmp_path / "out" / "estimates.json").read_text())["specularities"]
    return meta, sensor_like.score(specs, truth, normal)
