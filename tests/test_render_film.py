"""Issue 62: the wet film levels the micro-relief (``material.film_thickness_mm``).

The film's free surface is the tissue's relief with each wave of in-surface wavenumber ``k``
kept by ``exp(-(k L)^4)``, ``L^4 = LEVELLING_MM h^3`` (:mod:`simtest.render.tissue`'s notes);
no film leaves today's relief bit for bit. Pure numpy, no render.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from simtest.cli import app
from simtest.render.tissue import (
    LEVELLING_MM,
    _field,
    relief_height,
    relief_normal,
    tissue_params,
)
from simtest.scene import SceneError, load_scene, with_overrides

#: The default colonoscope's relief (scenes/colonoscope.toml): 30 um RMS, waves 0.5 to 4 mm.
RELIEF = {"relief_mm": 0.03, "relief_scale_mm": 4.0, "relief_min_mm": 0.5, "film_variation": 0.5}


def _texture(**over):
    kw = {**RELIEF, **over}
    return tissue_params("mucosa", 3, kw.pop("relief_mm"), kw.pop("relief_scale_mm"), **kw)


def _points(n=2000, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-6.0, 6.0, (3, n))
    nrm = rng.normal(size=(3, n))
    return tuple(p), tuple(nrm / np.linalg.norm(nrm, axis=0))


def _today(p, n, t, weight=None):
    """The shading normal of the relief as simtest computed it before the film levelled it (the
    same operations in the same order): ``unit(n - (g - (g . n) n))``, ``g`` the relief's gradient
    (each wave's slope times ``weight``)."""
    g = [0.0, 0.0, 0.0]
    for j in range(len(t.relief_phase)):
        k = t.relief_k[j]
        a = t.relief_amp[j] if weight is None else t.relief_amp[j] * weight[j]
        c = a * np.cos(p[0] * float(k[0]) + p[1] * float(k[1]) + p[2] * float(k[2]) + float(t.relief_phase[j]))
        g = [g[i] + c * float(k[i]) for i in range(3)]
    gn = g[0] * n[0] + g[1] * n[1] + g[2] * n[2]
    s = [n[i] - (g[i] - gn * n[i]) for i in range(3)]
    inv = 1.0 / np.sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2])
    return tuple(x * inv for x in s)


@pytest.mark.parametrize("spread", [0.0, 0.45])
@pytest.mark.parametrize("subsurface", [0.0, 1.0])
def test_no_film_is_todays_relief_bit_for_bit(spread, subsurface):
    p, n = _points()
    t = _texture(subsurface_mm=subsurface, film_thickness_mm=0.0, film_thickness_spread=spread)
    ns, nd = relief_normal(np, p, n, t, diffuse=True)
    for got, want in zip(ns, _today(p, n, t)):
        assert np.array_equal(got, want)
    for got, want in zip(nd, _today(p, n, t, t.relief_diffuse)):
        assert np.array_equal(got, want)
    assert np.array_equal(relief_height(np, p, t, n), relief_height(np, p, t))


def test_a_thick_film_keeps_exp_minus_kl4_of_each_wave():
    """On a plane (normal z) under a uniform film, a least-squares projection of the film's
    height on the relief's own waves recovers each amplitude times ``exp(-(k L)^4)`` (to 1e-9 of
    the largest: the fit's round-off); waves above the cut-off ``k L = 1`` keep at most 1/e, those
    at ``k L >= 2`` at most e^-16."""
    h0 = 0.15
    t = _texture(film_thickness_mm=h0)
    L = (LEVELLING_MM * h0**3) ** 0.25
    rng = np.random.default_rng(1)
    xy = rng.uniform(-20.0, 20.0, (2, 6000))
    p, n = (xy[0], xy[1], np.zeros(6000)), (np.zeros(6000), np.zeros(6000), np.ones(6000))
    arg = [p[0] * k[0] + p[1] * k[1] + ph for k, ph in zip(t.relief_k, t.relief_phase)]
    basis = np.stack([np.sin(a) for a in arg] + [np.cos(a) for a in arg], axis=1)
    coef = np.linalg.lstsq(basis, relief_height(np, p, t, n), rcond=None)[0]
    kt = np.linalg.norm(t.relief_k[:, :2], axis=1)
    kept = np.exp(-(kt * L) ** 4)
    assert np.allclose(coef[:len(kt)], t.relief_amp * kept, rtol=0, atol=1e-9 * t.relief_amp.max())
    assert np.allclose(coef[len(kt):], 0.0, atol=1e-9 * t.relief_amp.max())
    assert np.any(kt * L >= 1.0) and np.all(kept[kt * L >= 1.0] <= math.exp(-1.0))
    assert np.all(kept[kt * L >= 2.0] <= math.exp(-16.0))
    assert kept[np.argmin(kt)] > 0.9  # the longest wave (4 mm, k L = 0.77 at most) stays


def _tan_tilt(a, b):
    """tan of the angle between unit vectors (3, N): |a x b| / (a . b)."""
    return np.linalg.norm(np.cross(a, b, axis=0), axis=0) / np.sum(a * b, axis=0)


@pytest.mark.parametrize("spread", [0.0, 0.8])
def test_the_film_tilts_one_wave_by_its_local_factor(spread):
    """One wave alone: the film's shading normal's tilt (its tangent) is the tissue's times
    ``exp(-(k_t L(q))^4)``, with the local thickness ``h_0 exp(-s f(q))``, ``k_t`` the wave's
    wavenumber in the tangent plane; the diffuse light keeps the tissue's relief."""
    p, n = _points(500, seed=4)
    h0 = 0.1
    t0 = _texture(film_thickness_mm=h0, film_thickness_spread=spread)
    for j in (0, 20, 39):
        amp = np.zeros_like(t0.relief_amp)
        amp[j] = t0.relief_amp[j]
        t = type(t0)(**{**t0.__dict__, "relief_amp": amp})
        bare = type(t0)(**{**t.__dict__, "film_level4": 0.0})
        tan = [_tan_tilt(np.stack(relief_normal(np, p, n, x)), np.stack(n)) for x in (t, bare)]
        k = t.relief_k[j]
        kn = sum(k[i] * n[i] for i in range(3))
        kt2 = k @ k - kn * kn
        h = h0 * np.exp(-spread * _field(np, p, t.film_k, t.film_phase))
        want = np.exp(-kt2**2 * LEVELLING_MM * h**3)
        ok = tan[1] > 1e-6  # where the wave tilts the tissue at all
        assert np.allclose(tan[0][ok] / tan[1][ok], want[ok], rtol=1e-9, atol=1e-12)  # float64 round-off
        nd_film = relief_normal(np, p, n, t, diffuse=True)[1]
        for a, b in zip(nd_film, relief_normal(np, p, n, bare)):
            assert np.array_equal(a, b)


@pytest.mark.parametrize(("key", "value"), [("film_thickness_mm", 2.0), ("film_thickness_mm", -0.1),
                                            ("film_thickness_spread", 3.0)])
def test_film_keys_out_of_range_are_one_readable_line(tmp_path, key, value):
    with pytest.raises(SceneError, match=f"material.{key}"):
        with_overrides(load_scene("colonoscope"), {f"material.{key}": value})
    scene = Path(load_scene("colonoscope").source)
    lines = [line for line in scene.read_text().replace("../meshes/", f"{scene.parent.parent}/meshes/").splitlines()
             if not line.startswith(f"{key} =")]
    at = lines.index("texture_seed = 0") + 1
    src = tmp_path / "film.toml"
    src.write_text("\n".join(lines[:at] + [f"{key} = {value}"] + lines[at:]) + "\n")
    res = CliRunner().invoke(app, ["render", str(src), "-o", str(tmp_path / "out")])
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert res.exit_code == 2 and len(lines) == 1, res.output
    assert lines[0].startswith("error:") and f"material.{key}" in lines[0] and "film.toml" in lines[0]
    assert not (tmp_path / "out").exists()
