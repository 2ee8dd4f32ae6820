"""``simtest crb``: the photometric fit against its Cramer-Rao bound, versus epsilon/d and noise.

Analytic planes (exact Phong images of :mod:`simtest.simulate.offset`): a plane at
``distance_mm`` tilted ``tilt_deg``, one inverse-square light ``epsilon/d x distance`` mm off the
camera along x, Phong n = 60, f = 200 px, a 65 x 65 px ROI, background 0.1 and white Gaussian
noise sigma (fraction of the lobe's peak). Per (epsilon/d, sigma): the bounds of
:func:`simtest.reconstruct.lightaware.photometric_crb` on the normal (RMS deg) and depth
(relative), and the photometric fit's RMS errors over seeded realisations.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
import typer
from rich.console import Console

matplotlib.use("Agg", force=False)

import matplotlib.pyplot as plt  # noqa: E402 - after choosing the back-end

from simtest._exit import BAD_INPUT, fail
from simtest._outdir import check_out_folder, write_out_folder
from simtest._io import atomic_write, atomic_write_json
from simtest.geometry.angles import angle_between_deg
from simtest.geometry.camera import project_points
from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct.lightaware import photometric_crb, photometric_fit
from simtest.simulate.offset import rig_plane_image, specular_point

__all__ = ["crb_command", "crb_study", "plot_crb", "MAX_REALISATIONS"]

ROUGHNESS = 60.0
BACKGROUND = 0.1
HALF_ROI = 32
#: Most noisy images per setting (time, not memory, is the limit: about two hours on one core).
MAX_REALISATIONS = 10_000
#: What ``simtest crb`` writes in its output folder (and all that may be there: it is replaced).
CRB_FILES = ("crb.json", "crb.png")


def _case(eps_over_d, distance_mm, tilt_deg):
    t = np.radians(tilt_deg)
    normal = np.array([0.0, np.sin(t), -np.cos(t)])
    rig = LightRig((Light((eps_over_d * distance_mm, 0.0, 0.0), 1.0, "inverse_square"),))
    X, depth = specular_point(normal, distance_mm, rig.lights[0].position_mm)
    size = 2 * HALF_ROI + 1
    K = np.array([[200.0, 0, 0], [0, 200.0, 0], [0, 0, 1.0]])
    x = project_points(X, K)
    K[0, 2], K[1, 2] = HALF_ROI - x[0] + 0.3, HALF_ROI - x[1] - 0.2
    img = rig_plane_image(K, (size, size), normal, distance_mm, rig, ROUGHNESS) + BACKGROUND
    return img, K, normal, depth, rig, project_points(X, K)


def crb_study(eps_over_d=(0.05, 0.1, 0.2, 0.3, 0.5), sigmas=(0.002, 0.005, 0.01),
              realisations: int = 20, seed: int = 0, distance_mm: float = 20.0,
              tilt_deg: float = 25.0) -> list[dict]:
    """Bound and achieved errors of the photometric fit on noisy analytic planes.

    Parameters
    ----------
    eps_over_d : sequence of float
        Light offsets over the plane distance.
    sigmas : sequence of float
        Noise standard deviations, fraction of the lobe's peak.
    realisations : int
        Noisy images per setting, seeded ``SeedSequence([seed, i, j, k])``.
    seed : int
    distance_mm, tilt_deg : float
        The plane.

    Returns
    -------
    list of dict
        One per (epsilon/d, sigma): ``eps_over_d``, ``sigma``, ``crb_normal_deg``,
        ``crb_depth_pct``, ``rms_normal_deg``, ``rms_depth_pct``, ``n_depth``, ``n``.
    """
    rows = []
    for i, e in enumerate(eps_over_d):
        img, K, normal, depth, rig, bp = _case(e, distance_mm, tilt_deg)
        for j, sigma in enumerate(sigmas):
            crb = photometric_crb(K, (0, 0), img.shape, normal, distance_mm, rig, ROUGHNESS, 1.0,
                                  sigma, background=(BACKGROUND, 0.0, 0.0), bp_uv=bp)
            errs, derrs = [], []
            for k in range(realisations):
                rng = np.random.default_rng(np.random.SeedSequence([seed, i, j, k]))
                noisy = img + rng.normal(0.0, sigma, img.shape)
                bp_n = np.array(np.unravel_index(np.argmax(noisy), noisy.shape)[::-1], float)
                est = photometric_fit(noisy, (0, 0), bp_n, K, rig, nominal_depth_mm=distance_mm)
                if est.normal is not None:
                    errs.append(float(angle_between_deg(est.normal, normal)))
                if est.depth_mm is not None:
                    derrs.append(100.0 * (est.depth_mm / depth - 1.0))
            rows.append({
                "eps_over_d": float(e), "sigma": float(sigma),
                "crb_normal_deg": crb.normal_deg, "crb_depth_pct": 100.0 * crb.depth_rel,
                "rms_normal_deg": float(np.sqrt(np.mean(np.square(errs)))) if errs else None,
                "rms_depth_pct": float(np.sqrt(np.mean(np.square(derrs)))) if derrs else None,
                "n_depth": len(derrs), "n": realisations,
            })
    return rows


def plot_crb(rows: list[dict], path) -> Path:
    """Figure: bound (lines) and achieved RMS (markers) against epsilon/d, one colour per sigma.

    Parameters
    ----------
    rows : list of dict
        From :func:`crb_study`.
    path : str or Path
        PNG file (written to a temporary name, then renamed).

    Returns
    -------
    Path
    """
    path = Path(path)
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    for k, sigma in enumerate(sorted({r["sigma"] for r in rows})):
        rs = sorted((r for r in rows if r["sigma"] == sigma), key=lambda r: r["eps_over_d"])
        x = [r["eps_over_d"] for r in rs]
        colour = f"C{k}"
        for ax, bound, got in ((axes[0], "crb_normal_deg", "rms_normal_deg"),
                               (axes[1], "crb_depth_pct", "rms_depth_pct")):
            ax.plot(x, [r[bound] for r in rs], "-", color=colour, label=f"bound, sigma {100 * sigma:g} %")
            ax.plot(x, [np.nan if r[got] is None else r[got] for r in rs], "o", color=colour,
                    label=f"photometric_fit, sigma {100 * sigma:g} %")
    axes[0].set_ylabel("normal error, RMS (deg)")
    axes[1].set_ylabel("depth error, RMS (%)")
    for ax in axes:
        ax.set_xlabel("light offset epsilon / d")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle("Photometric fit against its Cramer-Rao bound (analytic planes at 20 mm; unknown: "
                 "normal, distance, roughness, gain, background)", fontsize=9)
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=120, format="png"))
    plt.close(fig)
    return path


def crb_command(
    out: Path = typer.Option(Path("reports/crb"), "--out", "-o",
                             help="Output folder (default: reports/crb under the current folder)."),
    realisations: int = typer.Option(20, "--realisations", "-n", min=2,
                                      help=f"Noisy images per setting (at most {MAX_REALISATIONS:,})."),
    seed: int = typer.Option(0, "--seed", min=0, help="Root seed."),
) -> None:
    """The photometric fit against its Cramer-Rao bound, on analytic planes.

    Writes OUT/crb.json (bound and achieved errors per light offset and noise level) and
    OUT/crb.png (the figure), replaced together: a run that fails leaves the previous pair.
    OUT must be new, empty or hold only these two files.

    Exit codes: 0 done; 2 bad usage; 4 OUT cannot be written (checked before running); 130
    interrupted.
    """
    if realisations > MAX_REALISATIONS:
        fail(f"-n/--realisations: {realisations:,} noisy images per setting exceed the maximum "
             f"of {MAX_REALISATIONS:,} (15 settings x {MAX_REALISATIONS:,} fits are already "
             "about two hours on one core)", BAD_INPUT)
    target = check_out_folder(out, CRB_FILES)
    console = Console(stderr=True)
    with console.status("fitting noisy analytic planes ..."):
        rows = crb_study(realisations=realisations, seed=seed)
    write_out_folder(out, target, lambda tmp: _fill(tmp, rows, seed, realisations), CRB_FILES)
    console = Console(soft_wrap=True)  # the results on stdout; progress was on stderr
    for r in rows:
        console.print(f"eps/d {r['eps_over_d']:.2f} sigma {100 * r['sigma']:.1f} %: normal "
                      f"{r['rms_normal_deg']:.3g} deg (bound {r['crb_normal_deg']:.3g}), depth "
                      f"{r['rms_depth_pct'] if r['rms_depth_pct'] is None else round(r['rms_depth_pct'], 3)} % "
                      f"(bound {r['crb_depth_pct']:.3g})", highlight=False)
    console.print(f"wrote {out / 'crb.json'} and {out / 'crb.png'}", highlight=False)


def _fill(tmp: Path, rows: list[dict], seed: int, realisations: int) -> None:
    """Write crb.json and crb.png into ``tmp``, the folder swapped in for OUT as a pair."""
    atomic_write_json(tmp / "crb.json", {"rows": rows, "seed": seed, "realisations": realisations})
    plot_crb(rows, tmp / "crb.png")
