"""Fixtures of the anatomy tests: the organ phantom's views, tomogram and session (organ_fixtures.py)."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # (--import-mode=importlib)

from organ_fixtures import _organ_session_template, organ_session, organ_tomogram, organ_views  # noqa: E402, F401
