"""Decision numbers live in one module with their provenance, never chosen on held-out data.

Issue 63: every decision number of detection, verification, light-aware fits and recommendation
in :mod:`simtest.decisions`, each with its unit, physical reason and provenance; a test fails when
a decision's provenance names held-out data. The AST walk below finds every module-level numeric
constant of ``simtest/reconstruct``; one that is not imported from :mod:`simtest.decisions` must be
listed in :data:`NOT_DECISIONS` with the reason it decides nothing a user gets.
"""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from simtest import decisions
from simtest.decisions import DATA, DECISIONS, data_side, decision

RECONSTRUCT = Path(decisions.__file__).parent / "reconstruct"

#: Module-level numbers of ``simtest/reconstruct`` that are no decision, with why. Status codes
#: and schema numbers name things; speed settings change no result (the bench and the golden set
#: say so); solver settings stop or start an iteration whose outcome the decisions judge.
_CODES = "a code or a count that names a thing, no threshold"
_SPEED = "a speed setting: results are the same either way"
_SOLVER = "a numerical solver setting (start, step, stop), judged by the decisions after"
_GUARD = "a memory or size guard with its own error message"
NOT_DECISIONS = {
    "isophote.ENCLOSE_FLOAT32_MARGIN_PX": _SPEED, "marching._EDGE_ENDS": _CODES,
    "marching.BATCH_MAX_PX": _SPEED,
    "pipeline.MMAP_THRESHOLD_BYTES": _SPEED, "pipeline.TRIM_THRESHOLD_BYTES": _SPEED,
    "candidates._GATHER_SIDE": _SPEED, "candidates._FEW": _SPEED,
    "detect.MULTIRES_CANDIDATES_MAX": _SPEED,
    "fit._S3_RCOND": _SOLVER,
    **{f"fit.{n}": _CODES for n in ("_D_EXPONENTS", "_CONIC_OF", "_CONIC_HALVES", "_SAMPSON_TERMS")},
    "frames.ESTIMATED_COUNT_SLACK": _CODES,
    "images.MAX_IMAGE_PIXELS": _GUARD, "images.C3VD_DEPTH_RANGE_MM": "C3VD's file format: 65535 is 100 mm",
    "io.SCHEMA_VERSION": _CODES, "io.READABLE_SCHEMAS": _CODES,
    "jpeg.BLOCK": "the JPEG standard's block side, 8 px", "jpeg.MCU_PX": "the JPEG standard's 4:2:0 MCU, 16 x 16 px",
    "jpeg.GRID_BLOCKS": _SPEED,
    "jpeg.MAX_STEP": "the baseline JPEG's largest 8-bit quantiser step",
    **{f"lightaware.colour.{n}": _SOLVER for n in ("_BODY_TRIM_PASSES", "_BODY_TRIM_SHARE",
                                                  "_BODY_BAND_DIVISOR", "_BODY_BAND_MAX",
                                                  "_FLUCTUATION_BOX", "_FLUCTUATION_PASSES",
                                                  "_FLUCTUATION_MIN_PIXELS")},
    **{f"lightaware.cubic.{n}": _SOLVER for n in ("_PROFILE_STEP", "_PROFILE_WIDE_START")},
    **{f"lightaware.patch.{n}": _SOLVER for n in ("_PROFILE_NFEV", "_PROFILE_TOL", "_PROFILE_PIXELS")},
    **{f"lightaware.patch_geometry.{n}": _SOLVER for n in ("_CUBIC_NEWTON_STEPS", "QUADRIC_PARAMS")},
    "lightaware.model._CB_FLOOR": _SOLVER, "lightaware.solve._GUARD": _SOLVER, "lightaware.model._FRESNEL_STEP": _SOLVER,
    "lightaware.model.BLINN_PER_PHONG": "a geometric identity: the mirror angle is twice the half vector's",
    "lightaware.patch._VALLEY_STEP": _SOLVER,
    "lightaware.plane.RETRY_START_DEPTHS": _SOLVER,
    "lightaware.plane_solve._SOLVES_KEPT": "a cache's size: a solve remembered is the solve redone, bit for bit",
    "lightaware.plane_model._BASES_KEPT": "a cache's size: a basis kept is the basis computed again, bit for bit",
    "lightaware.plane_solve.REFINE_MAX_PIXELS": "a cost bound: a larger ROI's refinement takes a sub-grid, "
                                                "its fit judged by the decisions after",
    "lightaware.plane_model.CAP_LIGHTS": "a cost bound: the pixel caps' share under a rig of more lights, "
                                         "its fit judged by the decisions after",
    **{f"lightaware.plane_model.{n}": _SOLVER for n in ("_NOT_FINITE_RESIDUAL",
                                                       "_ROUGHNESS_START_STEPS",
                                                       "_START_ROUGHNESS_GRID",
                                                       "_START_ROUGHNESS_GAIN")},
    **{f"lightaware.solve.{n}": _SOLVER for n in ("_LM_TOL", "_LM_TOL_FIRST_PASS",
                                                 "_CURVATURE_ALPHA", "_HAC_MAX_LAG")},
    "overlay.OVERLAY_BYTES_PER_PIXEL": _GUARD, "overlay.MAX_OVERLAY_PIXELS": _GUARD,
    **{f"overlay.{n}": "how the overlay is drawn, no result" for n in ("_SHIFT", "_DASH_PX")},
    "frame_prep.LUMA_FRAME_MIN_HIGHLIGHTS": _SPEED,
    "isophotes.RESOLVE_BATCH_ISOPHOTES": _SPEED, "isophotes.RESOLVE_BATCH_MIN": _SPEED,
    "isophotes.RESOLVE_BATCH_MIN_PX": _SPEED, "isophotes.RESOLVE_PENDING_MAX_BYTES": _SPEED,
    "isophotes.FIRST_BATCH_SIDE_PX": _SPEED,
    "table.TABLE_SCHEMA_VERSION": _CODES, "table.ROW_GROUP_ROWS": _SPEED,
    "verify.WINDOWED_AREA_MAX": _SPEED, "verify._PANEL_MARGIN_PX": _SPEED,
    "evidence_pixels._HIT_JOIN_PX": _SPEED,
    "verify._FLAT_SLACK": "float32 rounding slack of an exact test (30 ulps)",
    "view3d.MAX_SURFACE_GRID": _GUARD,
    "rig_pairs.DEPTH_SAMPLES": "a sampling density of a predicted curve (within 0.1 px of it)",
    "rig_pairs._MOST_CUTS": "a cost bound on a sampling density: one depth step cut into at most this many "
                            "pieces (a step whose image runs off towards the horizon; a frame is narrower)",
    "verify._REACH_T": "the isovalue NEIGHBOUR_REACH is stated at: a unit of it, not a threshold",
}


def _is_number_literal(node: ast.AST) -> bool:
    if isinstance(node, ast.Constant):
        return isinstance(node.value, (int, float)) and not isinstance(node.value, bool)
    if isinstance(node, ast.UnaryOp):
        return _is_number_literal(node.operand)
    if isinstance(node, ast.BinOp):
        return _is_number_literal(node.left) and _is_number_literal(node.right)
    if isinstance(node, (ast.Tuple, ast.List)):
        return bool(node.elts) and all(_is_number_literal(e) for e in node.elts)
    if isinstance(node, ast.Call) and getattr(node.func, "attr", "") in ("array", "sqrt"):
        return bool(node.args) and all(_is_number_literal(a) for a in node.args)
    return False


def module_numbers(root: Path = RECONSTRUCT) -> set[str]:
    """``module.NAME`` of every module-level UPPER_CASE name bound to a number literal."""
    found = set()
    for path in sorted(root.rglob("*.py")):
        module = ".".join(path.relative_to(root).with_suffix("").parts)
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.Assign) and len(node.targets) == 1:
                target, value = node.targets[0], node.value
            elif isinstance(node, ast.AnnAssign):
                target, value = node.target, node.value
            else:
                continue
            if isinstance(target, ast.Name) and target.id.lstrip("_").isupper() \
                    and value is not None and _is_number_literal(value):
                found.add(f"{module}.{target.id}")
    return found


def test_every_number_of_the_reconstruction_is_a_decision_or_says_why_not():
    found = module_numbers()
    unlisted = sorted(found - set(NOT_DECISIONS))
    assert not unlisted, (f"numbers defined outside simtest.decisions: {unlisted}; move each "
                          f"decision there with its provenance, or list it in NOT_DECISIONS")
    stale = sorted(set(NOT_DECISIONS) - found)
    assert not stale, f"NOT_DECISIONS lists names that are gone: {stale}"


def test_the_scan_finds_a_decision_written_back_into_a_module(tmp_path):
    # The check above could pass by finding nothing: a planted module-level threshold is found.
    (tmp_path / "verify.py").write_text("import numpy as np\nCONTRAST_MIN = 0.6\n"
                                        "W = np.array([1.0, -2.0])\n_X = (1, 2)\nname = 3\n")
    assert module_numbers(tmp_path) == {"verify.CONTRAST_MIN", "verify.W", "verify._X"}


def test_every_decision_has_a_unit_a_reason_and_a_known_provenance():
    assert len(DECISIONS) >= 60
    for name, d in DECISIONS.items():
        assert getattr(decisions, name) is d.value, name
        assert d.unit.strip() and len(d.why) >= 40, name
        assert d.basis in ("physics", "convention", "tuned"), name
        assert (d.basis == "tuned") == bool(d.chosen_on), name
        assert not d.chosen_on or d.n.strip(), f"{name}: a tuned decision says what was counted"


def test_no_decision_is_chosen_on_held_out_data():
    for name, d in DECISIONS.items():
        for data in d.chosen_on:
            assert DATA[data].side == "tuning", f"{name} was chosen on held-out {data}"
    assert {d.side for d in DATA.values()} == {"tuning", "held_out"}


def test_recording_a_decision_on_held_out_data_fails():
    held = next(k for k, d in DATA.items() if d.side == "held_out")
    with pytest.raises(ValueError, match="held-out"):
        decision("_TEST_ONLY", 1.0, "px", "x" * 40, basis="tuned", stage="detection",
                 chosen_on=(held,), n="1")
    with pytest.raises(ValueError, match="names its data"):
        decision("_TEST_ONLY", 1.0, "px", "x" * 40, basis="tuned", stage="detection")
    with pytest.raises(ValueError, match="unknown dataset"):
        decision("_TEST_ONLY", 1.0, "px", "x" * 40, basis="tuned", stage="detection",
                 chosen_on=("no-such-data",), n="1")
    assert "_TEST_ONLY" not in DECISIONS


def test_the_modules_apply_the_decisions_values():
    # A module that kept its own copy of a number would drift from the one documented here.
    from simtest.reconstruct import jpeg, recommend, settings, verify
    from simtest.reconstruct.lightaware import solve
    from simtest.tolerances import TOL

    assert verify.CONTRAST_MIN is decisions.CONTRAST_MIN
    assert verify.COEFFICIENTS is decisions.CONFIDENCE_COEFFICIENTS
    assert jpeg.PERIODICITY_MIN is decisions.JPEG_PERIODICITY_MIN
    assert recommend.DEPTH_REL_SIGMA_CEILING is decisions.DEPTH_RELEASE_REL_SIGMA
    assert solve.CLUSTER_PX is decisions.SIGMA_CLUSTER_PX
    assert settings.ReconSettings().peak_rel == decisions.PEAK_REL
    assert settings.ReconSettings.for_frames().isovalues == decisions.FRAME_ISOVALUES
    assert TOL.depth_rel_sigma_max == decisions.DEPTH_OBSERVABLE_REL_SIGMA
    # The two depth bounds are two decisions (observability at the noise floor; release).
    assert decisions.DEPTH_RELEASE_REL_SIGMA < decisions.DEPTH_OBSERVABLE_REL_SIGMA


@pytest.mark.parametrize("seed, side", [(0, "tuning"), (1, "held_out"), (1000, "held_out"),
                                        (np.int64(0), "tuning")])
def test_a_suite_run_says_which_side_its_figures_come_from(seed, side):
    assert data_side(seed) == side
