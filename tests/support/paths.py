"""Where the tests find the repository and the shared data beside it."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CMAPSS = ROOT.parent / "shared" / "data" / "cmapss"
FD001 = CMAPSS / "train_FD001.txt"
