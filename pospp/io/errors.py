"""Ingestion errors and non-fatal ingestion issues.

``IngestError`` stops ingestion; ``IngestIssue`` is a record kept with the data read
(``FlightLog.issues``) and later written to ``messages.parquet``. Both carry the facts needed to
find the problem in the file: the file, the topic, the message index within that topic (0-based,
file order), the header stamp and the MCAP log time (int64 ns), and for broken files the byte
offset.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

__all__ = ["IngestError", "IngestIssue", "MissingTopicError", "Severity"]

Severity = Literal["info", "warning", "error"]


def _facts(
    file: str | None,
    topic: str | None,
    index: int | None,
    time_ns: int | None,
    log_time_ns: int | None,
    byte_offset: int | None,
) -> str:
    parts = []
    if file is not None:
        parts.append(f"file={file}")
    if topic is not None:
        parts.append(f"topic={topic}")
    if index is not None:
        parts.append(f"index={index}")
    if time_ns is not None:
        parts.append(f"stamp_ns={time_ns}")
    if log_time_ns is not None:
        parts.append(f"log_time_ns={log_time_ns}")
    if byte_offset is not None:
        parts.append(f"byte_offset={byte_offset}")
    return " [" + ", ".join(parts) + "]" if parts else ""


class IngestError(ValueError):
    """An input file violates the data contract (docs/formats.md); ingestion stops.

    Attributes
    ----------
    reason : str
        What is wrong, with expected versus got.
    file, topic : str or None
    index : int or None
        Message index within ``topic`` (0-based, file order).
    time_ns, log_time_ns : int or None
        Header stamp and MCAP log time of that message [ns].
    byte_offset : int or None
        Where in the file reading broke, for corrupt files.
    issues : tuple of IngestIssue
        Findings recorded before ingestion stopped (e.g. where a corrupt file broke), so that
        the caller can still write them to ``messages.parquet``.
    """

    def __init__(
        self,
        reason: str,
        *,
        file: str | None = None,
        topic: str | None = None,
        index: int | None = None,
        time_ns: int | None = None,
        log_time_ns: int | None = None,
        byte_offset: int | None = None,
        issues: tuple[IngestIssue, ...] = (),
    ) -> None:
        self.reason = reason
        self.issues = tuple(issues)
        self.file = file
        self.topic = topic
        self.index = index
        self.time_ns = time_ns
        self.log_time_ns = log_time_ns
        self.byte_offset = byte_offset
        super().__init__(reason + _facts(file, topic, index, time_ns, log_time_ns, byte_offset))


class MissingTopicError(IngestError):
    """A required topic is not in an intact file: the configuration names a topic the log
    does not have (``[input] imu_topic``, ``fix_topic``); the message lists those it has."""


@dataclass(frozen=True)
class IngestIssue:
    """A finding that does not stop ingestion (or, for ``severity="error"`` on a truncated
    file, one that stopped reading but left usable data).

    Attributes
    ----------
    severity : {"info", "warning", "error"}
    file, topic : str or None
    index : int or None
        Message index within ``topic`` (0-based, file order) of the first message concerned.
    time_ns : int or None
        Its header stamp [ns].
    message : str
        Human-readable description with the numbers.
    log_time_ns, byte_offset : int or None
        MCAP log time [ns] and file offset [bytes], when relevant.
    """

    severity: Severity
    file: str | None
    topic: str | None
    index: int | None
    time_ns: int | None
    message: str
    log_time_ns: int | None = None
    byte_offset: int | None = None

    def __str__(self) -> str:
        facts = _facts(
            self.file, self.topic, self.index, self.time_ns, self.log_time_ns, self.byte_offset
        )
        return f"{self.severity}: {self.message}{facts}"
