"""What :func:`~simtest.reconstruct.pipeline.reconstruct` returns: one frame's estimates as a list
(brightest first) that also gives them as arrays and tables: BPs ``(N, 2)``, statuses ``(N,)``,
normals ``(N, E, 3)``, the rows of ``estimates.parquet`` and the ``estimates.json`` document.
"""

from __future__ import annotations

import numpy as np

from simtest.geometry.cameras import PinholeCamera
from simtest.reconstruct.io import dumps, estimate_to_dict, estimates_document
from simtest.reconstruct.table import arrow, estimates_batch

__all__ = ["Reconstruction", "NORMAL_COLUMNS"]

#: The normals of :meth:`Reconstruction.normals`, in order.
NORMAL_COLUMNS = ("paper_selected", "cone_axis", "joint_cone_axis", "bp_ray", "recommended")


class Reconstruction(list):
    """The estimates of one frame (a list, brightest first), what detection left out, and tables.

    Parameters
    ----------
    estimates : iterable of SpecularityEstimate
        One per examined candidate.
    n_components : int
        Bright components detection found in the frame (or its ROI).
    n_unexamined : int
        Components not examined because of ``max_candidates`` (the smallest ones); they have no
        estimate. 0 when every component was examined.
    max_candidates : int or None
        The cap in force (None: none).
    K : array_like of shape (3, 3), optional
        The pinhole intrinsics the frame was reconstructed with, px (None for another camera
        model), recorded by :meth:`to_json`.
    image_shape : tuple of int, optional
        The frame's ``(H, W, ...)``.
    isovalues : tuple of float
        The isovalues t of the reconstruction.
    normalise : str
        What the isovalues are relative to (``ReconSettings.normalise``).

    Examples
    --------
    >>> r = Reconstruction([], n_components=0, isovalues=(0.7, 0.85))
    >>> r.normals().shape, r.statuses.shape
    ((0, 5, 3), (0,))
    """

    def __init__(self, estimates=(), *, n_components: int = 0, n_unexamined: int = 0, max_candidates: int | None = None,
                 K=None, image_shape=None, isovalues: tuple = (), normalise: str = "auto"):
        super().__init__(estimates)
        self.n_components = int(n_components)
        self.n_unexamined = int(n_unexamined)
        self.max_candidates = max_candidates
        self.K = None if K is None else np.asarray(K, dtype=np.float64)
        self.image_shape = None if image_shape is None else tuple(int(s) for s in image_shape)
        self.isovalues = tuple(float(t) for t in isovalues)
        self.normalise = str(normalise)

    @classmethod
    def of_frame(cls, estimates, detection, settings, camera, image_shape) -> Reconstruction:
        """The frame's Reconstruction from what ``reconstruct`` holds at its end.

        Parameters
        ----------
        estimates : list of SpecularityEstimate
        detection : Detection
            Its ``n_components`` and ``n_unexamined`` are recorded.
        settings : ReconSettings
            Its ``max_candidates``, ``isovalues`` and ``normalise`` are recorded.
        camera : CameraModel
            Its K is recorded where it is a pinhole camera.
        image_shape : tuple of int
        """
        return cls(estimates, n_components=detection.n_components, n_unexamined=detection.n_unexamined,
                   max_candidates=settings.max_candidates, K=camera.K if isinstance(camera, PinholeCamera) else None,
                   image_shape=image_shape, isovalues=settings.isovalues, normalise=settings.normalise.value)

    def detection_record(self) -> dict:
        """``{"components", "examined", "not_examined", "max_candidates"}`` for estimates.json."""
        return {"components": self.n_components, "examined": self.n_components - self.n_unexamined,
                "not_examined": self.n_unexamined, "max_candidates": self.max_candidates}

    @property
    def bp_px(self) -> np.ndarray:
        """The brightest points, ``(N, 2)`` float64 (u, v) in px, pixel centres at integers."""
        return np.array([e.bp_px for e in self], dtype=np.float64).reshape(-1, 2)

    @property
    def statuses(self) -> np.ndarray:
        """Each estimate's status (``"ok"`` or the reason it was rejected), ``(N,)`` str."""
        return np.array([e.status for e in self], dtype=str).reshape(-1)

    @property
    def ok(self) -> np.ndarray:
        """Which estimates have status ``ok``, ``(N,)`` bool."""
        return self.statuses == "ok"

    def normals(self, columns=NORMAL_COLUMNS) -> np.ndarray:
        """The normals of every estimate and estimator, ``(N, E, 3)``.

        Parameters
        ----------
        columns : sequence of str
            Which normals, by name (default :data:`NORMAL_COLUMNS`); ``"recommended"`` is the
            recommendation's, any other name an attribute of the estimate.

        Returns
        -------
        ndarray of shape (N, len(columns), 3)
            Unit normals in the OpenCV camera frame, facing the camera; NaN where an estimator
            gave none (a rejected candidate has only its BP ray).

        Raises
        ------
        ValueError
            For a name that is no normal of an estimate.
        """
        cols = tuple(columns)
        out = np.full((len(self), len(cols), 3), np.nan)
        for i, e in enumerate(self):
            for j, c in enumerate(cols):
                if c == "recommended":
                    v = e.recommended.normal
                elif hasattr(e, c):
                    v = getattr(e, c)
                else:
                    raise ValueError(f"normals: {c!r} is not a normal of an estimate; known: "
                                     f"{', '.join(NORMAL_COLUMNS)}")
                if v is not None:  # (else NaN)
                    out[i, j] = np.asarray(v, dtype=np.float64).reshape(3)
        return out

    def rows(self, include_points: bool = False) -> list[dict]:
        """One dict per estimate, as in ``estimates.json`` (JSON-ready, None for missing values)."""
        return [estimate_to_dict(e, include_points) for e in self]

    def to_arrow(self, *, frame: int = 0, source: str = "", include_points: bool = False):
        """The rows ``simtest reconstruct`` writes to ``estimates.parquet``, as an Arrow table.

        Parameters
        ----------
        frame : int
            The ``frame`` column's value.
        source : str
            The ``source`` column's value (a file name).
        include_points : bool
            Also the isophotes' contour points.

        Returns
        -------
        pyarrow.Table
            One row per estimate, the schema of :func:`~simtest.reconstruct.table.table_schema`.
        """
        return arrow()[0].Table.from_batches([estimates_batch(frame, source, self, include_points)])

    def to_json(self, *, indent: bool = False, include_points: bool = False, image=None) -> bytes:
        """The ``estimates.json`` document of this frame, UTF-8 bytes (orjson).

        Parameters
        ----------
        indent : bool
            Indent by two spaces.
        include_points : bool
            Also the isophotes' contour points.
        image : str or Path, optional
            The image file, recorded as text.

        Returns
        -------
        bytes

        Raises
        ------
        ValueError
            A value that is not finite where the schema wants a number (its key path named).
        """
        doc = estimates_document(self, K=self.K, image=image, image_shape=self.image_shape, isovalues=self.isovalues,
                                 normalise=self.normalise, include_points=include_points,
                                 detection=self.detection_record())
        return dumps(doc, indent=indent)
