"""Specimen metadata of a session, in a sidecar file ``S.specimen.json`` beside ``S.h5``.

Fields (all optional): ``specimen_id``, ``age_dpf`` (days post fertilisation, a number), ``strain``,
``treatment``, ``plate``, ``well``. The session file itself is not touched: the sidecar is written
atomically (temporary file in the same folder, then one rename) and read into every batch table.
A screen's manifest is a CSV with a ``session`` column (file name or path of the session; relative names are
taken from the manifest's folder) and any of the fields as further columns.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any, Mapping

from vastcal.errors import UserInputError
from vastcal.screen_table import SPECIMEN_FIELDS, atomic_write_bytes


def sidecar_path(session: str | Path) -> Path:
    """``S.specimen.json`` for session ``S.h5``."""
    return Path(session).with_suffix(".specimen.json")


def _clean(fields: Mapping[str, Any], source: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in fields.items():
        if v is None or (isinstance(v, str) and not v.strip()):
            continue
        if k not in SPECIMEN_FIELDS:
            raise UserInputError(f"{source}: unknown specimen field {k!r}; expected one of {', '.join(SPECIMEN_FIELDS)}")
        if k == "age_dpf":
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise UserInputError(f"{source}: age_dpf: expected a number of days >= 0, got {v!r}") from None
            if not math.isfinite(v) or v < 0:
                raise UserInputError(f"{source}: age_dpf: expected a number of days >= 0, got {v!r}")
        else:
            v = str(v).strip()
        out[k] = v
    return out


def read_specimen(session: str | Path) -> dict[str, Any]:
    """The specimen fields of a session (``{}`` when there is no sidecar or it is unreadable)."""
    try:
        data = json.loads(sidecar_path(session).read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(data, dict):
        return {}
    return {k: data[k] for k in SPECIMEN_FIELDS if data.get(k) not in (None, "")}


def annotate(session: str | Path, fields: Mapping[str, Any], *, source: str = "annotate") -> Path:
    """Merge ``fields`` into the session's sidecar (atomically); returns the sidecar path.

    Raises:
        UserInputError: the session does not exist, an unknown field, an age that is not a number >= 0.
    """
    path = Path(session)
    if not path.is_file():
        raise UserInputError(f"{path}: no such session file")
    new = _clean(fields, source)
    data = read_specimen(path)
    data.update(new)
    side = sidecar_path(path)
    atomic_write_bytes(side, (json.dumps(data, indent=1, sort_keys=True) + "\n").encode())
    return side


def annotate_from_manifest(manifest: str | Path) -> list[Path]:
    """Annotate every session listed in a CSV manifest (see the module docstring); returns the sidecars."""
    mpath = Path(manifest)
    try:
        with mpath.open(newline="") as f:
            rows = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise UserInputError(f"{mpath}: cannot read the manifest ({exc})") from None
    if not rows or "session" not in rows[0]:
        raise UserInputError(f"{mpath}: expected a CSV with a 'session' column and one row per session")
    plan = []
    for i, row in enumerate(rows, start=2):  # check every line before writing anything
        name = (row.pop("session") or "").strip()
        if not name:
            raise UserInputError(f"{mpath}: line {i}: session: expected a session file name, got an empty cell")
        target = Path(name) if Path(name).is_absolute() else mpath.parent / name
        if not target.is_file():
            raise UserInputError(f"{mpath}: line {i}: session: no such session file {target}")
        fields = {k: v for k, v in row.items() if k is not None}
        _clean(fields, f"{mpath}: line {i}")
        plan.append((target, fields, f"{mpath}: line {i}"))
    return [annotate(t, f, source=src) for t, f, src in plan]
