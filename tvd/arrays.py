"""The math library's array arguments checked for shape, with the argument's name: a (2, n)
array passed for an (n, 2) one is refused, not reshaped into other robots' coordinates, and
a wrong length says so rather than leaving numpy's "cannot reshape" to the caller.
"""

from __future__ import annotations

import numpy as np


def as_point(value: object, name: str) -> np.ndarray:
    """``value`` as a float (2,) array (a point or a planar vector); ValueError otherwise."""
    array = np.asarray(value, dtype=float)
    if array.shape != (2,):
        raise ValueError(f"{name} must have shape (2,), got {array.shape}")
    return array


def as_rows(value: object, name: str, n: int | None = None, width: int = 2) -> np.ndarray:
    """``value`` as a float (m, width) array (m = ``n`` when given; an empty sequence is
    (0, width)); ValueError naming ``name`` and the shape otherwise."""
    array = np.asarray(value, dtype=float)
    if array.size == 0 and n in (None, 0):
        return array.reshape(0, width)
    wanted = f"({'m' if n is None else n}, {width})"
    if array.ndim != 2 or array.shape[1] != width or (n is not None and array.shape[0] != n):
        raise ValueError(f"{name} must have shape {wanted}, got {array.shape}")
    return array


def as_values(value: object, name: str, n: int) -> np.ndarray:
    """``value`` as a float (n,) array; ValueError naming ``name`` and the shape otherwise."""
    array = np.asarray(value, dtype=float)
    if array.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {array.shape}")
    return array


def as_mask(value: object, name: str, n: int) -> np.ndarray:
    """``value`` as an (n,) bool array; ValueError for indices, 0/1 integers or another
    length (a boolean index and an integer one select different robots)."""
    array = np.asarray(value)
    if array.shape != (n,) or array.dtype != np.bool_:
        raise ValueError(f"{name} must be a ({n},) bool array, got {array.dtype} {array.shape}")
    return array


def still_mask(still: object | None, n: int) -> np.ndarray | None:
    """``still`` (robots that stand still: covswarm.tvd.control's module notes) as an (n,)
    bool array, None when no robot stands still; ValueError for another shape, or for a
    team all still (the laws and e_a are over the moving robots: there would be none)."""
    if still is None:
        return None
    mask = as_mask(still, "still", n)
    if not mask.any():
        return None
    if mask.all():
        raise ValueError("still: every robot stands still; at least one must move")
    return mask
