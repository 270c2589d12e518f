"""Where the data that ships with factory lives (tool library, default cell)."""

from __future__ import annotations

from pathlib import Path

#: The project's ``fixtures/`` folder: tool library and cell definitions.
FIXTURES = Path(__file__).resolve().parent.parent / "fixtures"
