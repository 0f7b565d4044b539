"""Shared test fixtures: locations of the outside reference data (never copied into the repo),
named pipes that cannot hang a test."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator
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


@pytest.fixture
def make_fifo() -> Iterator[Callable[[Path], Path]]:
    """Make named pipes (FIFOs) for tests of code that must refuse them (issue 38 item 12).

    Each gets a thread that, unless the test ends first, opens and closes the pipe's write end
    after 30 s: code that blocks on it (the old behaviour) then reads an empty file and the
    test fails instead of hanging the run.
    """
    events: list[threading.Event] = []

    def make(path: Path) -> Path:
        os.mkfifo(path)
        done = threading.Event()
        events.append(done)

        def unblock() -> None:
            if not done.wait(30.0):
                os.close(os.open(path, os.O_RDWR | os.O_NONBLOCK))

        threading.Thread(target=unblock, daemon=True).start()
        return path

    yield make
    for done in events:
        done.set()
