"""A faster ``__init__`` for the frozen dataclasses a frame builds by the thousand.

A frozen dataclass' generated ``__init__`` sets each field through ``object.__setattr__``; :func:`fast_init`
writes them straight into ``__dict__``, with the same signature, ``__post_init__`` called, the class still
frozen. ``tests/test_shared_helpers.py`` checks every decorated class against its generated ``__init__``.

Examples
--------
>>> from dataclasses import dataclass
>>> @fast_init
... @dataclass(frozen=True)
... class Point:
...     u: float
...     v: float = 0.0
>>> Point(1.5)
Point(u=1.5, v=0.0)
"""

from __future__ import annotations

import dataclasses

__all__ = ["GENERATED_INIT", "fast_init"]

#: Each class :func:`fast_init` decorated -> the ``__init__`` the dataclass decorator generated
#: (kept for the test that compares the two).
GENERATED_INIT: dict[type, object] = {}


def fast_init(cls: type) -> type:
    """Give a frozen dataclass an ``__init__`` that fills the instance's ``__dict__`` directly.

    Parameters
    ----------
    cls : type
        A class decorated with ``@dataclass(frozen=True)`` (apply this decorator above it),
        without ``slots``, whose fields are all set by ``__init__`` (no ``init=False``), given
        positionally or by keyword (no ``kw_only``), with plain defaults (no ``default_factory``).

    Returns
    -------
    type
        ``cls``, its ``__init__`` replaced.

    Raises
    ------
    TypeError
        ``cls`` is not such a dataclass.
    """
    params = getattr(cls, "__dataclass_params__", None)
    if params is None or not params.frozen or "__slots__" in cls.__dict__:
        raise TypeError(f"fast_init: {cls.__qualname__} is not a frozen dataclass without slots")
    args, body, defaults = [], [], {}
    for f in dataclasses.fields(cls):
        if not f.init or f.kw_only or f.default_factory is not dataclasses.MISSING:
            raise TypeError(f"fast_init: {cls.__qualname__}.{f.name} is init=False, kw_only or has a "
                            "default_factory")
        if f.default is dataclasses.MISSING:
            args.append(f.name)
        else:
            defaults[f"_default_{f.name}"] = f.default
            args.append(f"{f.name}=_default_{f.name}")
        body.append(f"    d[{f.name!r}] = {f.name}")
    if hasattr(cls, "__post_init__"):
        body.append("    self.__post_init__()")
    src = f"def __init__(self, {', '.join(args)}):\n    d = self.__dict__\n" + "\n".join(body) + "\n"
    namespace: dict = {}
    exec(src, dict(defaults), namespace)  # noqa: S102 - built from the class' own field names
    init = namespace["__init__"]
    init.__qualname__ = f"{cls.__qualname__}.__init__"
    init.__module__ = cls.__module__
    init.__annotations__ = dict(cls.__init__.__annotations__)  # the generated signature's
    GENERATED_INIT[cls] = cls.__init__
    cls.__init__ = init
    return cls
