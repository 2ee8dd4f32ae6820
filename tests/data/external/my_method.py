"""An external estimator in 20 lines: the BP ray, from OpenCV alone (the README's example)."""
import cv2
import numpy as np


def bp_ray_cv(frame, camera, rig, response):
    # each bright blob's brightest pixel, and the normal facing back along its viewing ray
    gray = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
    gray = cv2.GaussianBlur(gray.astype(np.float32), (5, 5), 1.0)
    n, labels = cv2.connectedComponents((gray >= 0.8 * gray.max()).astype(np.uint8))
    vu = [np.unravel_index(np.argmax(np.where(labels == i, gray, -np.inf)), gray.shape)
          for i in range(1, n)]
    bp = np.asarray(vu, dtype=float).reshape(-1, 2)[:, ::-1]  # (u, v), px
    return {"bp_px": bp, "normal": -camera.pixel_to_ray(bp)}
