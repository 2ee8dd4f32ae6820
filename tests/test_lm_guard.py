"""The light-aware fits' Levenberg-Marquardt solves repeat bit for bit.

SciPy's C MINPACK (1.15 to 1.17.1) recomputes a column's norm in qrfac one element too far; past the
last column of the Jacobian it reads heap garbage, so the same solve, made twice, could end in two
places (on the bench's real tile with a two-guide rig: three outcomes in five runs of the same fits).
simtest's solves carry a guard column that is pivoted last and reads a zero there
(:func:`simtest.reconstruct.lightaware.solve.lm_least_squares`); where the garbage did not matter,
the guarded solve is the unguarded one, bit for bit.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares

from simtest.geometry.lights import Light, LightRig
from simtest.geometry.response import SensorResponse
from simtest.reconstruct.images import load_image
from simtest.reconstruct.light_fits import with_light_aware
from simtest.reconstruct.lightaware.plane_solve import forget_solves
from simtest.reconstruct.lightaware.solve import lm_least_squares
from simtest.reconstruct.pipeline import reconstruct
from simtest.resources import real_dir


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 5), st.booleans())
def test_the_guard_changes_no_bit_of_a_solve_the_bug_leaves_alone(seed, n, scaled):
    # a well-conditioned exponential fit (no column's norm collapses: qrfac never reads past a column)
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, 30 + 7 * n)
    truth = rng.uniform(0.5, 2.0, n)
    y = sum(truth[k] * np.exp(-(k + 1) * t) for k in range(n)) + 0.01 * rng.normal(size=len(t))

    def fun(p):
        return sum(p[k] * np.exp(-(k + 1) * t) for k in range(n)) - y

    x0 = np.ones(n)
    kw = dict(x_scale=rng.uniform(0.5, 2.0, n)) if scaled else {}
    plain = least_squares(fun, x0, method="lm", ftol=1e-10, xtol=1e-10, **kw)
    guarded = lm_least_squares(fun, x0, ftol=1e-10, xtol=1e-10, **kw)
    assert np.array_equal(guarded.x, plain.x) and guarded.nfev == plain.nfev
    assert np.array_equal(guarded.fun, plain.fun) and guarded.cost == plain.cost and guarded.status == plain.status


def test_a_real_tiles_light_aware_fits_repeat_bit_for_bit():
    # two tiles' glints under a two-guide rig, every fit's outcome (the stomach tile's curved patch fit: 745
    # evaluations to patch_misfit), repeated after other allocations; before the guard the polyp tile's glint
    # had its quadric profile end in two places over repeats of one process
    cases = []
    glints = (("hyperkvasir_tile_r2c3_polyp.png", (159.0, 50.9)), ("hyperkvasir_tile_r0c0_stomach.png", (60.1, 144.9)))
    for name, bp in glints:
        img = load_image(real_dir() / name)
        h, w = img.shape[:2]
        K = np.array([[140.0, 0, (w - 1) / 2], [0, 140.0, (h - 1) / 2], [0, 0, 1]])
        glint = min((e for e in reconstruct(img, K) if e.ok), key=lambda e: np.hypot(*np.subtract(e.bp_px, bp)))
        cases.append((img, K, [glint]))
    rig = LightRig(tuple(Light((x, 0.0, 0.0), 1.0, "inverse_square", 0.0) for x in (-4.0, 4.0)))
    seen = set()
    for k in range(3):
        forget_solves()
        junk = [np.random.default_rng(k).random(500 * (j + k + 1)) for j in range(30)]  # the heap moved
        outcome = []
        for img, K, oks in cases:
            for est in with_light_aware(img, oks, K, rig, cubic=False, response=SensorResponse("srgb", clip=255.0)):
                outcome += [(f, r.status, r.n_evaluations, None if r.normal is None else r.normal.tobytes())
                            for f, r in sorted(est.light_aware.items())]
        assert any(f == "quadric_fit" and n for f, _, n, _ in outcome)  # (a curved patch fit was solved)
        seen.add(tuple(outcome))
        del junk
    assert len(seen) == 1


def test_a_batched_solve_stops_at_the_iterate_that_ran_off_not_at_a_trial():
    # r(p) = exp(-p): LM drives p to infinity and only the budget ends it. A stop that says p past 5 is lost ends
    # the solve at the first iterate LM accepted beyond 5 (status -1, the reason its message, the residual there);
    # with a stop that never fires the solve is the unstopped one, bit for bit
    def fun(p):
        return np.exp(-np.atleast_2d(p)[:, :1]) if np.ndim(p) == 2 else np.exp(-p[:1])

    free_run = lm_least_squares(fun, [0.0], batched=True, max_nfev=400)
    never = lm_least_squares(fun, [0.0], batched=True, max_nfev=400, stop=lambda p: "")
    assert np.array_equal(never.x, free_run.x) and never.nfev == free_run.nfev and never.status == free_run.status
    accepted = []  # the points LM took its Jacobian at (its iterates): the cost never rises along them
    def seen(p):
        accepted.append(p.copy())
        return "lost" if p[0] > 5.0 else ""

    r = lm_least_squares(fun, [0.0], batched=True, max_nfev=400, stop=seen)
    assert r.status == -1 and r.message == "lost" and r.x[0] > 5.0 and r.x[0] == accepted[-1][0]
    assert r.fun[0] == np.exp(-r.x[0]) and r.cost == 0.5 * r.fun[0] ** 2
    assert all(a[0] <= 5.0 for a in accepted[:-1]) and 0 < r.nfev < free_run.nfev
    assert np.all(np.diff([np.exp(-a[0]) for a in accepted]) <= 0)


def test_the_budget_counts_lm_steps_and_a_ran_off_solve_counts_them_too():
    # quadric_fit's and cubic_patch_fit's budgets are max_nfev (k + 1) LM steps: SciPy >= 1.16's method "lm"
    # counts a step's residual evaluation, not the finite differences' (n more points, one batch, at each
    # accepted step). Were SciPy to count those again, each budget would shrink (k + 1)-fold: this fails first
    points = {"n": 0}

    def fun(p):  # r(p) = exp(-p): no minimum, only the budget ends the solve
        q = np.atleast_2d(p)
        points["n"] += len(q)
        return np.exp(-q[:, :1]) if np.ndim(p) == 2 else np.exp(-p[:1])

    budget = 40
    free_run = lm_least_squares(fun, [0.0], batched=True, max_nfev=budget)
    assert free_run.status == 0 and free_run.nfev == budget
    # the finite differences' points came on top: n = 1 at each accepted step (the guard's column reuses the
    # step's own residual); counted in nfev, none would have
    assert 0 < points["n"] - budget <= budget
    # a solve stopped where it ran off reports its steps in the same unit: at most the free run's at that iterate
    stopped = lm_least_squares(fun, [0.0], batched=True, max_nfev=budget, stop=lambda p: "lost" if p[0] > 5.0 else "")
    assert stopped.status == -1 and 0 < stopped.nfev < budget
