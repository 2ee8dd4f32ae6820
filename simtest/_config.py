"""The pieces the config models share: strict field types and the one-line error of a bad key.

Scene, suite and dataset files are pydantic dataclasses (``CONFIG``: unknown keys refused, no NaN or
infinity). A float field takes an integer, an integer field an integral float; nothing else is coerced.
:func:`validation_error` turns pydantic's report into ``"<file>: <key.path>: <reason> (got <value>)"``.
"""

from __future__ import annotations

import functools
import json
import math
import tomllib
from typing import Annotated, Any, Callable, TypeVar, get_args, get_origin

from pydantic import AfterValidator, BeforeValidator, ConfigDict, Strict, TypeAdapter, ValidationError

from simtest._checks import keyed_error

__all__ = ["CONFIG", "Num", "Int", "Str", "Bool", "Vec2", "Vec3", "Floats", "Number", "Scalar", "key_path",
           "parse_toml", "validated", "validation_error"]

E = TypeVar("E", bound=Exception)

#: The config models' settings: unknown keys refused, NaN and infinities refused.
CONFIG = ConfigDict(extra="forbid", allow_inf_nan=False)


def _integral(v: Any) -> Any:
    return int(v) if isinstance(v, float) and v.is_integer() else v


def _list_of(n: int) -> Callable[[Any], Any]:
    def check(v: Any) -> Any:
        if not isinstance(v, (list, tuple)) or len(v) != n:
            raise ValueError(f"expected a list of {n} numbers")
        return v
    return check


def _non_empty(v: Any) -> Any:
    if not isinstance(v, (list, tuple)) or not v:
        raise ValueError("expected a list of numbers")
    return v


def _number(v: Any) -> Any:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError("expected a number")
    return v


def _scalar(v: Any) -> Any:
    if isinstance(v, (dict, list, tuple)) or (isinstance(v, float) and not math.isfinite(v)):
        raise ValueError("expected a finite scalar (a number, a string or true/false)")
    return v


#: One finite value: a number, a string, a boolean (a TOML date too).
Scalar = Annotated[Any, AfterValidator(_scalar)]
#: A finite number kept as given (an int stays an int: a suite's case key is its JSON).
Number = Annotated[Any, AfterValidator(_number)]
#: A finite number (an integer is taken as a float).
Num = Annotated[float, Strict()]
#: An integer (an integral float is taken).
Int = Annotated[int, BeforeValidator(_integral), Strict()]
Str = Annotated[str, Strict()]
Bool = Annotated[bool, Strict()]
Vec2 = Annotated[tuple[Num, Num], BeforeValidator(_list_of(2))]
Vec3 = Annotated[tuple[Num, Num, Num], BeforeValidator(_list_of(3))]
#: A non-empty list of numbers.
Floats = Annotated[tuple[Num, ...], BeforeValidator(_non_empty), AfterValidator(tuple)]

_BOUNDS = {"greater_than": ("gt", ">"), "greater_than_equal": ("ge", ">="),
           "less_than": ("lt", "<"), "less_than_equal": ("le", "<=")}
_EXPECTED = {"int_type": "an integer", "int_parsing": "an integer", "int_from_float": "an integer",
             "float_type": "a number", "float_parsing": "a number", "bool_type": "true or false",
             "bool_parsing": "true or false", "string_type": "a string",
             "finite_number": "a finite number", "list_type": "a list", "tuple_type": "a list",
             "dict_type": "a table", "dataclass_type": "a table", "model_type": "a table",
             "dataclass_args_type": "a table"}


def key_path(loc: tuple, prefix: str = "") -> str:
    """A pydantic location as the dotted key a person writes: ``sweep[0].values[2]``."""
    out = prefix
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "<root>"


def _num(v: Any) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _bounds(items: Any) -> dict:
    """The ``gt``/``ge``/``lt``/``le`` bounds among pydantic metadata (``Field`` or annotated-types)."""
    b: dict = {}
    for m in items:
        b.update({n: getattr(m, n) for n in ("gt", "ge", "lt", "le") if getattr(m, n, None) is not None})
        b.update(_bounds(getattr(m, "metadata", None) or ()))
    return b


def _item_bounds(tp: Any) -> dict:
    """The bounds of the first bounded type inside ``tp`` (``list[Annotated[float, Field(gt=0)]]``)."""
    if get_origin(tp) is Annotated:
        args = get_args(tp)
        return _bounds(args[1:]) or _item_bounds(args[0])
    for arg in get_args(tp):
        if b := _item_bounds(arg):
            return b
    return {}


def _model_of(tp: Any) -> Any:
    """``tp`` itself or the first member of a union (``Model | None``) that is a model."""
    return next((a for a in (tp, *get_args(tp)) if hasattr(a, "__pydantic_fields__")), None)


def _keys_at(cls: Any, loc: tuple) -> str | None:
    """The keys of the table at ``loc`` of ``cls``, for the message of an unknown key."""
    for part in loc:
        model = _model_of(cls)
        if model is None or part not in model.__pydantic_fields__:
            return None
        cls = model.__pydantic_fields__[part].annotation
    model = _model_of(cls)
    return None if model is None else ", ".join(model.__pydantic_fields__)


def _interval(cls: Any, loc: tuple) -> str | None:
    """The interval of the field (or list item) at ``loc`` of ``cls`` when both ends are bounded."""
    fields = getattr(cls, "__pydantic_fields__", None)
    if not fields or not loc or loc[0] not in fields:
        return None
    f, rest = fields[loc[0]], loc[1:]
    if len(rest) == 1 and isinstance(rest[0], int):  # an item of a list or tuple of bounded numbers
        b = _item_bounds(f.annotation)
    elif rest:
        return _interval(f.annotation, rest)
    else:
        b = _bounds(f.metadata)
    lo = ("(", b["gt"]) if "gt" in b else ("[", b["ge"]) if "ge" in b else None
    hi = (")", b["lt"]) if "lt" in b else ("]", b["le"]) if "le" in b else None
    return None if lo is None or hi is None else f"{lo[0]}{_num(lo[1])}, {_num(hi[1])}{hi[0]}"


def validation_error(error: type[E], source: str, exc: ValidationError, prefix: str = "",
                     known: Callable[[tuple], str | None] | None = None, cls: Any = None) -> E:
    """The one-line error of the first problem pydantic found.

    Parameters
    ----------
    error : type
        The validator's exception class (``SceneError``, ``SuiteError``, ...).
    source : str
        The file being validated (or ``"<dict>"``).
    exc : pydantic.ValidationError
    prefix : str
        Key path of the validated table inside the file, "" for the root.
    known : callable, optional
        ``loc -> "a, b, c"``: the keys allowed where an unknown key was found.
    cls : type, optional
        The model validated: a value out of a two-sided range names the whole interval.

    Returns
    -------
    Exception
        ``error("<source>: <key.path>: <reason>")``, the reason naming the value and any bound.
    """
    e = exc.errors(include_url=False)[0]
    kind, loc, value, ctx = e["type"], tuple(e["loc"]), e.get("input"), e.get("ctx") or {}
    if kind in ("extra_forbidden", "unexpected_keyword_argument"):
        keys = known(loc[:-1]) if known is not None else _keys_at(cls, loc[:-1])
        reason = "unknown key" + (f" (known keys: {keys})" if keys else "")
    elif kind == "missing":
        return error(f"{source}: {key_path(loc, prefix)}: missing")
    elif kind in _BOUNDS:
        name, op = _BOUNDS[kind]
        interval = _interval(cls, loc)
        reason = "out of range: must be " + (f"in {interval}" if interval else f"{op} {_num(ctx[name])}")
    elif kind == "literal_error":  # every choice is a string
        reason = f"must be one of {ctx['expected']}" if isinstance(value, str) else "expected a string"
    elif kind in ("too_short", "too_long"):
        n = ctx.get("min_length", ctx.get("max_length"))
        reason = f"expected at {'least' if kind == 'too_short' else 'most'} {n} entr{'y' if n == 1 else 'ies'}"
    elif kind == "string_too_short":
        reason = "must not be empty"
    elif kind in _EXPECTED:
        reason = f"expected {_EXPECTED[kind]}"
    else:
        reason = str(ctx.get("error", e["msg"])) if kind in ("value_error", "assertion_error") else e["msg"]
    return keyed_error(error, source, key_path(loc, prefix), reason, _plain(value))


def _plain(value: Any) -> Any:
    """``value`` as :func:`simtest._checks.format_value` can show it (JSON, else its repr)."""
    try:
        json.dumps(value)
        return value
    except (TypeError, ValueError):
        return repr(value)


def parse_toml(data: bytes, source, error: type[Exception]) -> dict:
    """The table of a TOML file's bytes ``data``, or ``error("<source>: not valid TOML: <why>")``.

    Raises
    ------
    error
        When ``data`` is not UTF-8 (an image given for a config, say) or not TOML.
    """
    try:
        return tomllib.loads(data.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise error(f"{source}: not valid TOML: {exc}") from None


@functools.cache
def _adapter(cls: Any) -> TypeAdapter:
    return TypeAdapter(cls)


def validated(cls: Any, data: Any, error: type[Exception], source: str, prefix: str = "",
              known: Callable[[tuple], str | None] | None = None) -> Any:
    """``data`` validated as ``cls`` (a pydantic dataclass or a type), or the one-line ``error``.

    Parameters
    ----------
    cls : type
        What ``data`` must be.
    data : object
        The table (or value) as read from the file.
    error, source, prefix, known
        As for :func:`validation_error`.

    Returns
    -------
    object
        The validated value.

    Raises
    ------
    error
        ``"<source>: <prefix.key>: <reason>"`` for the first problem found.
    """
    try:
        return _adapter(cls).validate_python(data)
    except ValidationError as exc:
        raise validation_error(error, source, exc, prefix, known, cls) from None
