"""Shared test fixtures: locations of the outside reference data (never copied into the repo)."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
REFERENCE_CASES = SHARED / "reference_cases"
REAL_DATA = SHARED / "data"


@pytest.fixture(scope="session")
def reference_cases() -> Path:
    """../shared/reference_cases, or skip with the reason."""
    if not (REFERENCE_CASES / "flight_survey_errors.mcap").exists():
        pytest.skip(f"reference cases not found at {REFERENCE_CASES} (outside data, not in repo)")
    return REFERENCE_CASES


@pytest.fixture(scope="session")
def real_data() -> Path:
    """../shared/data, or skip with the reason."""
    if not REAL_DATA.is_dir():
        pytest.skip(f"real datasets not found at {REAL_DATA} (outside data, not in repo)")
    return REAL_DATA
