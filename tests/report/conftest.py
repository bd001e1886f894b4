"""Fixtures of the report tests: small phantom sessions, measured or not (tests/reconstruct/session_fixtures.py)."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "reconstruct"))  # (--import-mode=importlib)

from session_fixtures import _measured_template, measured_session, session_factory, small_views  # noqa: E402, F401
