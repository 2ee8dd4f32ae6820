"""A rendered case's tissue texture drawn for each realisation (``texture = "per_realisation"``):
the case's realisations then sample the tissue as well as the sensor's noise."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.harness import protocols
from simtest.harness.protocols import make_runner, realisation_overrides
from simtest.constants import MAX_SEED
from simtest.harness.suite import SceneSetting, SuiteError, realisation_seed, resolve_suite_path, suite_from_dict

#: The endoscope suite's line that draws a texture for each realisation.
PER_REALISATION = 'texture = "per_realisation"\n'


def one_texture_endoscope(directory):
    """The endoscope suite file without its ``texture`` key, written into ``directory``: its cases
    keep the keys and seeds ``validate`` gave before the suite drew a texture for each
    realisation, and render the scene's one texture (the frames earlier tests were set on)."""
    text = resolve_suite_path("endoscope").read_text()
    assert text.count(PER_REALISATION) == 1
    path = directory / "endoscope.toml"
    path.write_text(text.replace(PER_REALISATION, ""))
    return path


def _suite(texture=None, scene="colonoscope_plane"):
    base = {"texture": texture} if texture is not None else {}
    return suite_from_dict({"suite": {"name": "t", "protocol": "rendered", "scene": scene, "realisations": 2},
                            "base": base,
                            "sweep": [{"name": "noise", "parameter": "sensor.gaussian_sigma",
                                       "values": [0.0, 0.01]}]})


def test_the_default_leaves_the_case_keys_and_the_seeds_as_they_were():
    # a suite that does not name the key keeps its cases' keys (and so every realisation's seeds);
    # naming its default says the same thing
    plain, named = _suite(), _suite("scene")
    assert [c.key for c in plain.cases] == [c.key for c in named.cases]
    assert all("texture" not in c.key for c in plain.cases)
    drawn = _suite("per_realisation")
    assert all('"texture":"per_realisation"' in c.key for c in drawn.cases)
    assert {c.scene_setting.texture for c in drawn.cases} == {"per_realisation"}
    assert {c.scene_setting.texture for c in plain.cases} == {"scene"}


@pytest.mark.parametrize("texture, scene, needle", [
    ("each", "colonoscope_plane", "texture: must be one of 'scene' or 'per_realisation' (got \"each\")"),
    ("per_realisation", "sphere", "texture: needs a procedural tissue"),
])
def test_a_bad_texture_is_named(texture, scene, needle):
    with pytest.raises(SuiteError, match=needle.replace("(", r"\(").replace(")", r"\)")):
        _suite(texture, scene)


@settings(max_examples=50, deadline=None)
@given(root=st.integers(0, 2**31 - 1), key=st.text(min_size=1, max_size=20), i=st.integers(0, 1000))
def test_the_render_seed_is_the_first_word_and_the_texture_seed_the_second(root, key, i):
    ss = realisation_seed(root, key, i)
    first = int(ss.generate_state(1, np.uint32)[0]) & MAX_SEED
    plain = realisation_overrides(SceneSetting(overrides={}), ss)
    assert plain == {"render.seed": first}
    drawn = realisation_overrides(SceneSetting(overrides={}, texture="per_realisation"), ss)
    assert drawn["render.seed"] == first
    assert drawn["material.texture_seed"] == int(ss.generate_state(2, np.uint32)[1]) & MAX_SEED
    assert 0 <= drawn["material.texture_seed"] <= MAX_SEED


def test_the_runner_renders_each_realisation_with_its_own_texture(monkeypatch):
    # the spec each realisation renders: its texture seed differs from the other's and is the
    # same when the realisation runs again
    case = _suite("per_realisation").cases[0]
    runner = make_runner(case, ("bp_ray",))
    seen = []

    class Stop(Exception):
        pass

    def render(spec, seed):
        seen.append((seed, spec.material.texture_seed, spec.render.seed))
        raise Stop

    monkeypatch.setattr(protocols, "render_scene", render)
    for i in (0, 1, 0):
        with pytest.raises(Stop):
            runner.run(realisation_seed(7, case.key, i))
    (s0, t0, r0), (s1, t1, _), again = seen
    assert s0 == r0 and t0 != t1 and again == seen[0]
    assert t0 != runner.spec.material.texture_seed or t1 != runner.spec.material.texture_seed
