"""Second-order forward-mode automatic differentiation in two variables (numpy arrays).

A :class:`Jet` carries a value and its exact first and second partial derivatives with respect
to two parameters (a, b): ``(f, f_a, f_b, f_aa, f_ab, f_bb)``, propagated by the chain and
product rules (truncated Taylor arithmetic, Griewank & Walther, "Evaluating Derivatives", 2nd ed.,
SIAM 2008, ch. 13): exact to rounding, no step size (:mod:`~simtest.scene.meshes.haustral`). Our
own because no required dependency does automatic differentiation.

Components are broadcasting numpy arrays; a vector-valued jet keeps its components along the last
axis (``shape (..., 3)``); :meth:`Jet.vec` lifts a scalar jet so that it broadcasts against one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["Jet", "variable", "constant", "compose"]

_Fn = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Jet:
    """Value and first and second partial derivatives in the parameters (a, b).

    Attributes
    ----------
    v, a, b, aa, ab, bb : ndarray
        ``f, df/da, df/db, d2f/da2, d2f/dadb, d2f/db2`` (broadcastable arrays).
    """

    v: np.ndarray
    a: np.ndarray
    b: np.ndarray
    aa: np.ndarray
    ab: np.ndarray
    bb: np.ndarray

    # -- linear operations ------------------------------------------------------------------
    def _parts(self) -> tuple[np.ndarray, ...]:
        return (self.v, self.a, self.b, self.aa, self.ab, self.bb)

    def __add__(self, other: Jet | float | np.ndarray) -> Jet:
        if isinstance(other, Jet):
            return Jet(*(x + y for x, y in zip(self._parts(), other._parts(), strict=True)))
        return Jet(self.v + other, self.a, self.b, self.aa, self.ab, self.bb)

    __radd__ = __add__

    def __neg__(self) -> Jet:
        return Jet(*(-x for x in self._parts()))

    def __sub__(self, other: Jet | float | np.ndarray) -> Jet:
        return self + (-other)

    def __rsub__(self, other: float | np.ndarray) -> Jet:
        return (-self) + other

    def __mul__(self, other: Jet | float | np.ndarray) -> Jet:
        if not isinstance(other, Jet):
            return Jet(*(x * other for x in self._parts()))
        f, g = self, other
        return Jet(
            f.v * g.v,
            f.a * g.v + f.v * g.a,
            f.b * g.v + f.v * g.b,
            f.aa * g.v + 2.0 * f.a * g.a + f.v * g.aa,
            f.ab * g.v + f.a * g.b + f.b * g.a + f.v * g.ab,
            f.bb * g.v + 2.0 * f.b * g.b + f.v * g.bb,
        )

    __rmul__ = __mul__

    def __truediv__(self, other: Jet | float | np.ndarray) -> Jet:
        if not isinstance(other, Jet):
            return self * (1.0 / np.asarray(other, dtype=np.float64))
        return self * other.apply(lambda x: 1.0 / x, lambda x: -1.0 / (x * x), lambda x: 2.0 / (x * x * x))

    def __rtruediv__(self, other: float | np.ndarray) -> Jet:
        return self.apply(lambda x: 1.0 / x, lambda x: -1.0 / (x * x), lambda x: 2.0 / (x * x * x)) * other

    def __getitem__(self, key: object) -> Jet:
        return Jet(*(np.broadcast_to(x, np.broadcast_shapes(*(y.shape for y in self._parts())))[key]
                     for x in self._parts()))

    def vec(self) -> Jet:
        """This scalar jet with a trailing axis of length 1 (broadcasts against a vector jet)."""
        return Jet(*(np.asarray(x)[..., None] for x in self._parts()))

    # -- elementary functions ---------------------------------------------------------------
    def apply(self, f: _Fn, f1: _Fn, f2: _Fn) -> Jet:
        """``phi(self)`` for a scalar function phi given with its first two derivatives."""
        d0, d1, d2 = f(self.v), f1(self.v), f2(self.v)
        return Jet(
            d0,
            d1 * self.a,
            d1 * self.b,
            d2 * self.a * self.a + d1 * self.aa,
            d2 * self.a * self.b + d1 * self.ab,
            d2 * self.b * self.b + d1 * self.bb,
        )

    def sin(self) -> Jet:
        """Sine."""
        s, c = np.sin(self.v), np.cos(self.v)
        return self.apply(lambda _: s, lambda _: c, lambda _: -s)

    def cos(self) -> Jet:
        """Cosine."""
        s, c = np.sin(self.v), np.cos(self.v)
        return self.apply(lambda _: c, lambda _: -s, lambda _: -c)

    def exp(self) -> Jet:
        """Exponential."""
        e = np.exp(self.v)
        return self.apply(lambda _: e, lambda _: e, lambda _: e)

    def sqrt(self) -> Jet:
        """Square root (of a positive value)."""
        r = np.sqrt(self.v)
        return self.apply(lambda _: r, lambda _: 0.5 / r, lambda _: -0.25 / (r * r * r))

    def square(self) -> Jet:
        """Square."""
        return self * self


def constant(value: np.ndarray | float) -> Jet:
    """A jet with zero derivatives."""
    v = np.asarray(value, dtype=np.float64)
    z = np.zeros_like(v)
    return Jet(v, z, z, z, z, z)


def variable(value: np.ndarray | float, which: str) -> Jet:
    """The parameter ``a`` or ``b`` itself at ``value`` (unit first derivative in it)."""
    v = np.asarray(value, dtype=np.float64)
    z, one = np.zeros_like(v), np.ones_like(v)
    if which == "a":
        return Jet(v, one, z, z, z, z)
    if which == "b":
        return Jet(v, z, one, z, z, z)
    raise ValueError(f"variable: which must be 'a' or 'b', got {which!r}")


def compose(u: Jet, f0: np.ndarray, f1: np.ndarray, f2: np.ndarray) -> Jet:
    """``F(u(a, b))`` for a (vector) function F of one variable, given F, F', F'' at ``u.v``.

    Parameters
    ----------
    u : Jet
        Scalar jet of the inner function (shape S).
    f0, f1, f2 : ndarray of shape S + (k,) or S
        F, dF/du and d2F/du2 at ``u.v``; with a trailing vector axis the scalar jet is lifted.
    """
    if np.ndim(f0) == np.ndim(u.v) + 1:
        u = u.vec()
    return Jet(f0, f1 * u.a, f1 * u.b, f2 * u.a * u.a + f1 * u.aa,
               f2 * u.a * u.b + f1 * u.ab, f2 * u.b * u.b + f1 * u.bb)
