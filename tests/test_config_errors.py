"""The one-line error of a bad config value (simtest._config.validation_error), per kind of fault.

Every config model (scene, suite, dataset) reports through it, so each case here pins the line a
person reads: ``<file>: <key.path>: <reason> (got <value>)``, with the whole interval where a range
has two ends.
"""

from __future__ import annotations

from typing import Annotated, Literal

import pytest
from pydantic import Field
from pydantic.dataclasses import dataclass

from simtest._config import CONFIG, Int, Num, Number, Str, Vec3, validated


class _Bad(ValueError):
    pass


@dataclass(frozen=True, config=CONFIG)
class _Inner:
    level: Num = Field(0.5, gt=0.0, le=1.0)


@dataclass(frozen=True, config=CONFIG)
class _Model:
    count: Int = Field(1, ge=0, le=10)
    scale: Num = Field(1.0, gt=0.0)
    mode: Literal["a", "b"] = "a"
    name: Str = Field("x", min_length=1)
    where: Vec3 = (0.0, 0.0, 0.0)
    levels: list[Annotated[Num, Field(gt=0.0, lt=1.0)]] = Field(default_factory=lambda: [0.5],
                                                                 min_length=1)
    inner: _Inner = _Inner()
    x: Number = 0


@pytest.mark.parametrize(("data", "line"), [
    ({"count": 11}, "count: out of range: must be in [0, 10] (got 11)"),
    ({"scale": -2}, "scale: out of range: must be > 0 (got -2)"),
    ({"levels": [0.5, 1.5]}, "levels[1]: out of range: must be in (0, 1) (got 1.5)"),
    ({"inner": {"level": 0}}, "inner.level: out of range: must be in (0, 1] (got 0)"),
    ({"mode": "c"}, "mode: must be one of 'a' or 'b' (got \"c\")"),
    ({"mode": True}, "mode: expected a string (got true)"),
    ({"count": 2.5}, "count: expected an integer (got 2.5)"),
    ({"count": "3"}, "count: expected an integer (got \"3\")"),
    ({"scale": "big"}, "scale: expected a number (got \"big\")"),
    ({"scale": float("nan")}, "scale: expected a finite number (got nan)"),
    ({"name": 3}, "name: expected a string (got 3)"),
    ({"where": [1, 2]}, "where: expected a list of 3 numbers (got [1, 2])"),
    ({"x": True}, "x: expected a number (got true)"),
    ({"colour": "red"}, "colour: unknown key (known keys: count, scale, mode, name, where, levels, "
                        "inner, x) (got \"red\")"),
    ({"inner": {"lvl": 1}}, "inner.lvl: unknown key (known keys: level) (got 1)"),
    ({"inner": 3}, "inner: expected a table (got 3)"),
    ({"levels": []}, "levels: expected at least 1 entry (got [])"),
    ({"name": ""}, "name: must not be empty (got \"\")"),
])
def test_each_fault_reads_as_one_line_naming_key_reason_and_value(data, line):
    with pytest.raises(_Bad) as err:
        validated(_Model, data, _Bad, "f.toml", "sec")
    assert str(err.value) == f"f.toml: sec.{line}"


def test_what_the_types_take():
    # a float field takes an int, an int field an integral float; nothing else is coerced
    got = validated(_Model, {"count": 3.0, "scale": 2, "where": [1, 2, 3], "x": 4}, _Bad, "f")
    assert (got.count, got.scale, got.where, got.x) == (3, 2.0, (1.0, 2.0, 3.0), 4)
    assert type(got.count) is int and type(got.scale) is float and type(got.x) is int
