"""Fixtures of the stability suite (issue 8): scenes written as .glb, tiny bakes."""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:  # stab_helpers imports as a top-level module
    sys.path.insert(0, str(HERE))
