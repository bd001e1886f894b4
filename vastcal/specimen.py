"""Specimen metadata of a session: given at acquisition (in the session), or attached later (a sidecar).

Fields (all optional): ``specimen_id``, ``age_dpf`` (days post fertilisation, a number), ``strain``,
``treatment``, ``plate``, ``well``.

* At acquisition (``vastcal acquire --specimen ID=F12,age_dpf=5,strain=AB`` or ``--specimen FILE``): stored in
  the session's start record (attribute ``specimen``, JSON), written with the session's first bytes.
* Later (``vastcal annotate``): the session file itself is not touched; the fields go to a sidecar
  ``S.specimen.json`` beside ``S.h5``, written atomically (temporary file in the same folder, then one rename).
  A sidecar's fields override the session's own.

Both are read into every batch table. A screen's manifest is a CSV with a ``session`` column (file name or path
of the session; relative names are taken from the manifest's folder) and any of the fields as further columns;
as YAML, a mapping of session file names to field mappings. ``acquire --specimen MANIFEST`` takes the entry of
the session it writes; a YAML file of fields alone describes one specimen.
"""

from __future__ import annotations

import csv
import json
import logging
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from vastcal.errors import UserInputError
from vastcal.screen_table import SPECIMEN_FIELDS, atomic_write_bytes

log = logging.getLogger(__name__)

ALIASES: dict[str, str] = {"id": "specimen_id", "age": "age_dpf"}
"""Short names accepted by ``--specimen`` and in YAML (case-insensitive)."""

MAX_SPECIMEN_FILE_BYTES = 4 << 20
"""A specimen file or manifest larger than this is refused (a screen of 10 000 rows is well under 1 MB)."""


def sidecar_path(session: str | Path) -> Path:
    """``S.specimen.json`` for session ``S.h5``."""
    return Path(session).with_suffix(".specimen.json")


def _clean(fields: Mapping[str, Any], source: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in fields.items():
        if v is None or (isinstance(v, str) and not v.strip()):
            continue
        if k not in SPECIMEN_FIELDS:
            raise UserInputError(
                f"{source}: unknown specimen field {k!r}; expected one of {', '.join(SPECIMEN_FIELDS)}"
            )
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


def read_sidecar(session: str | Path) -> dict[str, Any]:
    """The fields of the session's sidecar ``S.specimen.json`` (``{}`` when there is none).

    Raises:
        UserInputError: the sidecar exists but cannot be read, or is not a JSON object of specimen fields
            (one line naming the file and what was expected).
    """
    side = sidecar_path(session)
    try:
        raw = side.read_bytes()
    except FileNotFoundError:
        return {}
    except OSError as exc:
        raise UserInputError(f"{side}: cannot read the specimen sidecar ({exc.strerror or exc})") from None
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise UserInputError(
            f"{side}: not a specimen sidecar ({type(exc).__name__}: {str(exc).splitlines()[0][:120]}); expected a JSON "
            f"object of {', '.join(SPECIMEN_FIELDS)}: repair or remove it, then annotate again"
        ) from None
    if not isinstance(data, dict):
        raise UserInputError(
            f"{side}: not a specimen sidecar (a JSON {type(data).__name__}); expected a JSON object of "
            f"{', '.join(SPECIMEN_FIELDS)}: repair or remove it, then annotate again"
        )
    return {k: data[k] for k in SPECIMEN_FIELDS if data.get(k) not in (None, "")}


def read_specimen(session: str | Path) -> dict[str, Any]:
    """The sidecar's specimen fields, for readers that go on without them: ``{}`` when there is no sidecar, and
    ``{}`` with a warning naming the file when it is unreadable (:func:`read_sidecar` raises instead)."""
    try:
        return read_sidecar(session)
    except UserInputError as exc:
        log.warning("%s (its fields are left out)", exc)
        return {}


def specimen_fields(session: str | Path) -> dict[str, Any]:
    """Every specimen field of a session, in :data:`SPECIMEN_FIELDS` order: those stored at acquisition, overridden
    by the sidecar's (an unreadable sidecar is left out with a warning)."""
    merged = {**session_specimen(session), **read_specimen(session)}
    return {k: merged[k] for k in SPECIMEN_FIELDS if k in merged}


def annotate(session: str | Path, fields: Mapping[str, Any], *, source: str = "annotate") -> Path:
    """Merge ``fields`` into the session's sidecar (atomically); returns the sidecar path.

    Raises:
        UserInputError: the session does not exist, an unknown field, an age that is not a number >= 0, or its
            sidecar exists but is not one (left as it is).
    """
    path = Path(session)
    if not path.is_file():
        raise UserInputError(f"{path}: no such session file")
    new = _clean(fields, source)
    data = read_sidecar(path)  # an unreadable sidecar is refused, never replaced
    data.update(new)
    side = sidecar_path(path)
    atomic_write_bytes(side, (json.dumps(data, indent=1, sort_keys=True) + "\n").encode())
    return side


def annotate_sessions(sessions: list[str | Path], fields: Mapping[str, Any]) -> list[Path]:
    """Merge the same ``fields`` into the sidecar of every session (``vastcal annotate S1.h5 S2.h5 --strain AB``).

    Every session and sidecar is checked before anything is written.

    Raises:
        UserInputError: as :func:`annotate`, for the first session that would fail (nothing written then).
    """
    plan = []
    for s in sessions:
        if not Path(s).is_file():
            raise UserInputError(f"{s}: no such session file")
        plan.append((Path(s), dict(fields), "annotate"))
    _clean(fields, "annotate")
    return _annotate_all(plan)


def annotate_from_manifest(manifest: str | Path) -> list[Path]:
    """Annotate every session listed in a CSV or YAML manifest (see the module docstring); returns the sidecars.

    Every entry is checked before anything is written.
    """
    mpath = Path(manifest)
    if mpath.suffix.lower() in (".yaml", ".yml"):
        data = _yaml(_read_small(mpath, "--manifest"), str(mpath)) if mpath.is_file() else None
        if not isinstance(data, dict) or not data or not all(isinstance(v, dict) for v in data.values()):
            raise UserInputError(
                f"{mpath}: expected a YAML mapping of session file names to specimen fields"
                + ("" if mpath.is_file() else " (no such file)")
            )
        plan = []
        for key, fields in data.items():
            target = Path(str(key)) if Path(str(key)).is_absolute() else mpath.parent / str(key)
            if not target.is_file():
                raise UserInputError(f"{mpath}: {key}: no such session file {target}")
            clean = _clean({_key(k): v for k, v in fields.items()}, f"{mpath}: {key}")
            plan.append((target, clean, f"{mpath}: {key}"))
        return _annotate_all(plan)
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
    return _annotate_all(plan)


def _annotate_all(plan: list[tuple[Path, dict[str, Any], str]]) -> list[Path]:
    """Annotate every (session, fields, source) of a checked manifest; every sidecar is read first, so that an
    unreadable one refuses the whole manifest before anything is written."""
    for target, _, _ in plan:
        read_sidecar(target)
    return [annotate(t, f, source=src) for t, f, src in plan]


# ---------------------------------------------------------------- at acquisition


def _key(k: Any) -> str:
    k = str(k).strip()
    return ALIASES.get(k.lower(), k.lower() if k.lower() in SPECIMEN_FIELDS else k)


def parse_specimen_text(text: str, source: str = "--specimen") -> dict[str, Any]:
    """Fields from ``KEY=VALUE,KEY=VALUE`` (``ID=`` / ``id=`` for ``specimen_id``); checked as :func:`annotate` does.

    Raises:
        UserInputError: an item without ``=``, an unknown field, a bad age (one line naming ``source``).
    """
    fields: dict[str, Any] = {}
    for item in text.split(","):
        if not item.strip():
            continue
        if "=" not in item:
            raise UserInputError(
                f"{source}: {item.strip()!r}: expected KEY=VALUE (keys: ID, {', '.join(SPECIMEN_FIELDS[1:])}) "
                "or a YAML/CSV file"
            )
        k, v = item.split("=", 1)
        fields[_key(k)] = v.strip()
    out = _clean(fields, source)
    if not out:
        raise UserInputError(f"{source}: no fields given; expected KEY=VALUE pairs or a YAML/CSV file")
    return out


def _read_small(path: Path, source: str) -> str:
    try:
        with path.open("rb") as f:
            raw = f.read(MAX_SPECIMEN_FILE_BYTES + 1)
        if len(raw) > MAX_SPECIMEN_FILE_BYTES:
            raise UserInputError(
                f"{source}: {path}: larger than {MAX_SPECIMEN_FILE_BYTES} bytes; expected a specimen file or manifest"
            )
        return raw.decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise UserInputError(f"{source}: {path}: cannot read it ({exc})") from None


def specimen_for_session(spec: str, session: str | Path, source: str = "--specimen") -> dict[str, Any]:
    """The specimen fields for the session being written to ``session``, from ``spec``.

    ``spec`` is ``KEY=VALUE,…``; or a YAML file: either one specimen's fields, or a manifest mapping session
    file names (``larva_001.h5`` or its stem) to fields; or a CSV manifest with a ``session`` column.

    Raises:
        UserInputError: unreadable file, no entry for this session in a manifest, bad fields (one line).
    """
    path = Path(spec)
    if not path.is_file():
        if path.suffix.lower() in (".yaml", ".yml", ".csv", ".json") and "=" not in spec:
            raise UserInputError(f"{source}: {spec}: no such file")
        return parse_specimen_text(spec, source)
    name = Path(session).name
    names = {name, Path(session).stem}
    text = _read_small(path, source)
    if path.suffix.lower() == ".csv":
        try:
            rows = list(csv.DictReader(text.splitlines()))
        except csv.Error as exc:
            raise UserInputError(f"{source}: {path}: cannot read the manifest ({exc})") from None
        if not rows or "session" not in rows[0]:
            raise UserInputError(f"{source}: {path}: expected a CSV with a 'session' column and one row per session")
        for i, row in enumerate(rows, start=2):
            if {Path((row.get("session") or "").strip()).name, Path((row.get("session") or "").strip()).stem} & names:
                fields = {k: v for k, v in row.items() if k not in (None, "session")}
                return _clean(fields, f"{source}: {path}: line {i}")
        raise UserInputError(f"{source}: {path}: no row for session {name}; expected a 'session' cell {name}")
    data = _yaml(text, f"{source}: {path}")
    if not isinstance(data, dict) or not data:
        raise UserInputError(
            f"{source}: {path}: expected a mapping of specimen fields, or of session file names to fields"
        )
    if all(isinstance(v, dict) for v in data.values()):  # a manifest
        for key, fields in data.items():
            if {Path(str(key)).name, Path(str(key)).stem} & names:
                return _clean({_key(k): v for k, v in fields.items()}, f"{source}: {path}: {key}")
        raise UserInputError(f"{source}: {path}: no entry for session {name}; expected a key {name}")
    return _clean({_key(k): v for k, v in data.items()}, f"{source}: {path}")


def _yaml(text: str, source: str) -> Any:
    """YAML through the rig file's bounded loader (nesting, alias expansion); one-line errors naming ``source``."""
    import yaml

    from vastcal.config import _load_yaml, _TooLarge

    try:
        return _load_yaml(text)
    except _TooLarge as exc:
        raise UserInputError(f"{source}: refused: the YAML document {exc}") from None
    except yaml.YAMLError as exc:
        raise UserInputError(f"{source}: YAML syntax error ({str(exc).splitlines()[0]})") from None


def session_specimen(session: str | Path) -> dict[str, Any]:
    """The fields stored in the session at acquisition (start record ``specimen``); ``{}`` when none or unreadable."""
    from vastcal.errors import VastcalError
    from vastcal.session import Session

    try:
        with Session.open(session) as s:
            data = s.start_record.get("specimen")
    except (VastcalError, OSError):
        return {}
    if isinstance(data, str):
        try:
            data = json.loads(data)
        except ValueError:
            return {}
    if not isinstance(data, dict):
        return {}
    return {k: data[k] for k in SPECIMEN_FIELDS if data.get(k) not in (None, "")}
