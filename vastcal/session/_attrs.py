"""HDF5 attributes as Python values: dicts and lists stored as JSON text, NumPy scalars read back as Python's."""

from __future__ import annotations

import json
from typing import Any

import h5py
import numpy as np


def set_attrs(obj: h5py.HLObject, attrs: dict[str, Any]) -> None:
    """Write attributes (None values skipped); dicts and lists of non-numbers become JSON strings."""
    for k, v in attrs.items():
        if v is None:
            continue
        if isinstance(v, (dict, list, tuple)) and not (
            isinstance(v, (list, tuple)) and v and all(isinstance(x, (int, float)) for x in v)
        ):
            v = json.dumps(v)
        obj.attrs[k] = v


def attr_str(v: Any) -> Any:
    """Bytes as text; anything else unchanged."""
    return v.decode() if isinstance(v, bytes) else v


def plain(v: Any) -> Any:
    """A NumPy scalar or array as the Python value JSON and callers expect (others unchanged)."""
    if isinstance(v, np.generic):
        item = v.item()
        if isinstance(item, np.generic):  # long double, complex long double …: no Python twin
            return float(item.real) if np.issubdtype(item.dtype, np.number) else str(item)
        return item
    if isinstance(v, np.ndarray):
        return v.tolist()
    return v


def json_default(v: Any) -> Any:
    """``json.dumps`` fallback: NumPy values as Python's, anything else as its text."""
    p = plain(v)
    return str(p) if p is v else p


def decode_json(v: Any) -> Any:
    """An attribute value as written by :func:`set_attrs`: JSON text decoded, NumPy values made plain."""
    v = attr_str(v)
    if isinstance(v, str) and v[:1] in "[{":
        try:
            return json.loads(v)
        except ValueError:
            return v
    return plain(v)


def write_attrs(group: h5py.Group, attrs: dict[str, Any]) -> None:
    """Write attributes; dicts and lists of non-numbers are stored as JSON strings."""
    set_attrs(group, attrs)


def read_attrs(group: h5py.Group) -> dict[str, Any]:
    """Read attributes, decoding the JSON strings that :func:`write_attrs` wrote."""
    return {k: decode_json(v) for k, v in group.attrs.items()}
