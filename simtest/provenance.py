"""Where the decision numbers of :mod:`simtest.decisions` come from: the datasets the project holds or makes,
each on the tuning or the held-out side, and the record every decision is made with (:func:`decision`).

``basis`` says where a value comes from:

- ``"physics"``: derived from the image formation, the sensor or sampling theory (the reason says
  how); it was chosen on no data.
- ``"convention"``: a choice with no data behind it that a user may change (a default such as the
  isovalues' spacing); the reason says why this one.
- ``"tuned"``: chosen by looking at data, which ``chosen_on`` names (keys of :data:`DATA`) and
  ``n`` counts. Every dataset named there is on the tuning side: a decision is never chosen on
  data that judges it (``tests/test_decisions.py``).

:data:`DATA` declares each dataset and its side, ``"tuning"`` or ``"held_out"``. Claims and the README's
figures come from held-out data: renders at a root seed other than the tuning seeds
(:data:`TUNING_ROOT_SEEDS`), and real frames of other scopes that the project does not hold. The project's
only real frames (the Hyper-Kvasir banner and its tiles) are tuning data for every decision; the frame split
of ``simtest simreal`` (``simtest.render.simreal.REAL_SPLIT``) is a held-out half for the render calibration
only.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["DATA", "DECISIONS", "TUNING_ROOT_SEEDS", "DataSet", "Decision", "data_side", "decision"]


@dataclass(frozen=True)
class DataSet:
    """A dataset decisions may be chosen on, or claims judged on.

    Attributes
    ----------
    side : {"tuning", "held_out"}
    what : str
        What it is and where it lives.
    """

    side: str
    what: str


#: The datasets, by name. A decision's ``chosen_on`` names only tuning-side entries.
DATA: dict[str, DataSet] = {
    "banner-labelled": DataSet(
        "tuning", "the 24 frames of the Hyper-Kvasir banner collage (tests/data/real/"
        "hyperkvasir_banner.jpg, CC BY 4.0) with their hand labels (highlights_labelled.json, "
        "structures_labelled.json), all 24 frames"),
    "banner-tiles": DataSet(
        "tuning", "the three 280 x 280 px tiles cut from the same banner (tests/data/real/*.png)"),
    "bench-frames": DataSet(
        "tuning", "the synthetic 1350 x 1080 bench frames of benchmarks/ (10 Phong highlights, "
        "clean and with 2 % noise)"),
    "bundled-renders": DataSet(
        "tuning", "renders of the bundled scenes (scenes/*.toml) at render seed 0"),
    "suite-lightaware": DataSet(
        "tuning", "the lightaware suite (rendered planes under a light rig) at a tuning root seed"),
    "suite-lightaware-curved": DataSet(
        "tuning", "the lightaware-curved suite (sphere, cylinder, saddle, liver, colon) at a tuning "
        "root seed"),
    "suite-endoscope": DataSet(
        "tuning", "the endoscope suite (flat mucosa and colon wall under the colonoscope's two "
        "guides) at a tuning root seed"),
    "exact-planes": DataSet(
        "tuning", "closed-form 8-bit images of planes under an offset light (simtest.simulate), "
        "made for a decision and not kept"),
    "libjpeg-encodes": DataSet(
        "tuning", "frames encoded and decoded by OpenCV's libjpeg at qualities 25 to 98 (the "
        "endoscope suite's renders, textured noisy test images, sensor-like plane frames)"),
    "sensor-like-generated": DataSet(
        "tuning", "8-bit sRGB frames of planes under the two guides made by the tests' generators (tests/test_rig_pairs.py "
        "sensor_plane, tests/test_fused_tops.py ggx_plane) and benchmarks/sensor_like.py's (RANGES and CODED_NOISE at "
        "root seed 5, NEAR at 5 and 6) at seeds no held-out count names"),
    "sensor-like-independent": DataSet(
        "held_out", "8-bit sRGB frames of planes under two guides made by benchmarks/sensor_like.py (a "
        "generator sharing no code with the renderer or the tests' generators: Phong, Blinn-Phong, GGX and "
        "Cook-Torrance lobes, random K, guides, tissue colours, exposure, noise, PNG or JPEG) at its ROOT_SEED, "
        "NEAR_ROOT_SEED and CODED_NOISE_ROOT_SEED; judged only (`simtest bench --only sensor_like`, "
        "`sensor_like_near`, `sensor_like_coded_noise`)"),
    "suites-held-out-seeds": DataSet(
        "held_out", "every bundled suite run at a root seed outside TUNING_ROOT_SEEDS: the same "
        "scenes and settings, new noise, texture and relief draws"),
    "real-other-scopes": DataSet(
        "held_out", "real frames of scopes the project does not hold (colonoscopy phantom, in-vivo "
        "colonoscopy, laparoscopic liver), judged by eye outside the project"),
    "simreal-held-out-frames": DataSet(
        "held_out", "the held-out banner frames of simtest.render.simreal.REAL_SPLIT, held out "
        "for the render calibration only (the detection decisions saw every banner frame)"),
}

#: Root seeds of the suite runs that decisions were chosen on. A suite run at any other root seed
#: is held-out data (``suites-held-out-seeds``).
TUNING_ROOT_SEEDS = frozenset({0})


def data_side(seed: int) -> str:
    """Which side a suite run's figures come from.

    Parameters
    ----------
    seed : int
        The run's root seed.

    Returns
    -------
    str
        ``"tuning"`` for a root seed in :data:`TUNING_ROOT_SEEDS`, else ``"held_out"``.
    """
    return "tuning" if int(seed) in TUNING_ROOT_SEEDS else "held_out"


@dataclass(frozen=True)
class Decision:
    """One decision number and where it comes from.

    Attributes
    ----------
    value : float, int, tuple or ndarray
    unit : str
    why : str
        The physical reason (or, for a tuned value, what it separates and what was seen).
    basis : {"physics", "convention", "tuned"}
    chosen_on : tuple of str
        Keys of :data:`DATA` it was chosen on (empty unless tuned).
    n : str
        What was counted when it was chosen ("" unless tuned).
    applies_in : str
        The stage that applies it: detection, verification, light-aware or recommendation.
    """

    value: object
    unit: str
    why: str
    basis: str
    chosen_on: tuple[str, ...]
    n: str
    applies_in: str


#: Every decision, by the name its modules import.
DECISIONS: dict[str, Decision] = {}

_BASES = ("physics", "convention", "tuned")
_STAGES = ("detection", "verification", "light-aware", "recommendation")


def decision(name: str, value, unit: str, why: str, *, basis: str, stage: str,
             chosen_on: tuple[str, ...] = (), n: str = ""):
    """Record a decision number and return its value.

    Parameters
    ----------
    name : str
        The module-level name it is bound to in :mod:`simtest.decisions` (and imported by).
    value : float, int, tuple or ndarray
    unit : str
    why : str
    basis : {"physics", "convention", "tuned"}
    stage : {"detection", "verification", "light-aware", "recommendation"}
    chosen_on : tuple of str, optional
        Keys of :data:`DATA`; required (and tuning-side only) when ``basis`` is ``"tuned"``.
    n : str, optional
        What was counted when it was chosen.

    Returns
    -------
    object
        ``value``, unchanged.

    Raises
    ------
    ValueError
        For a name recorded twice, an unknown basis, stage or dataset, a tuned decision without
        data or with held-out data, or data named for an untuned one.
    """
    if name in DECISIONS:
        raise ValueError(f"decision {name} recorded twice")
    if basis not in _BASES or stage not in _STAGES:
        raise ValueError(f"decision {name}: basis {basis!r} / stage {stage!r} unknown")
    unknown = [d for d in chosen_on if d not in DATA]
    if unknown:
        raise ValueError(f"decision {name}: unknown dataset(s) {unknown}")
    if (basis == "tuned") != bool(chosen_on):
        raise ValueError(f"decision {name}: a tuned decision names its data, no other does")
    held = [d for d in chosen_on if DATA[d].side != "tuning"]
    if held:
        raise ValueError(f"decision {name}: chosen on held-out data {held}")
    DECISIONS[name] = Decision(value, unit, why, basis, tuple(chosen_on), n, stage)
    return value
