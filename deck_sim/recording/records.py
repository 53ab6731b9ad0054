"""The records of an MCAP episode log, read in one sequential pass that survives damage.

``read_records`` collects a log's schemas, channels, messages, metadata and attachments from its data section,
checking every CRC, and says where reading stopped if the data section is cut or damaged and how the summary
section is damaged if it is. ``EpisodeLog`` decodes what it returns; ``recover`` copies it into a new file.
"""

from __future__ import annotations

import dataclasses
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zstandard
from google.protobuf.message import DecodeError
from mcap.exceptions import EndOfFile, McapError, RecordLengthLimitExceeded
from mcap.records import Attachment, Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

FILE_ERRORS = (McapError, struct.error, EOFError, ValueError, IndexError, KeyError, zstandard.ZstdError)
"""What the mcap package raises on a damaged file (CRC errors are ``ValueError``)."""
DECODE_ERRORS = (*FILE_ERRORS, DecodeError, TypeError)
"""What decoding a damaged message or schema raises (protobuf's ``DecodeError``; ``TypeError`` from a descriptor
that does not build)."""
RECORD_LIMIT = 1 << 30  # bytes: a larger record length is corruption, not data


class LogError(ValueError):
    """An episode log cannot be used: missing, empty, not MCAP, corrupt or not a deck_sim log (the message names
    the file and the problem)."""


class TruncatedLogError(LogError):
    """The log ends before its data section does: its writer stopped mid-file (killed or crashed). ``recover``
    repairs it.

    (A log damaged inside, e.g. a chunk failing its CRC, raises ``LogError``; ``recover`` keeps what precedes the
    damage.)"""


@dataclass
class RawLog:
    """The records of a log's data section, in file order.

    Attributes:
        complete: The data section is whole: its ``DataEnd`` record (with its CRC) or the footer was read.
        stopped_at: Where and why reading stopped inside the data section ("" if it did not).
        summary_damage: Where and how the summary section (what follows the data: schemas and channels again,
            indexes, statistics, footer, closing magic) is damaged ("" if it is whole or absent).
    """

    header: Header | None = None
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    messages: list[Message] = field(default_factory=list)
    metadata: list[Metadata] = field(default_factory=list)
    attachments: list[Attachment] = field(default_factory=list)
    complete: bool = False
    stopped_at: str = ""
    summary_damage: str = ""


def _unchunked(records: Iterator[Any]) -> Iterator[Any]:
    """``records`` with each chunk replaced by the records it holds (CRC checked). A zstd chunk is decompressed
    as a stream and its size compared with the size its header declares afterwards: the mcap package allocates the
    declared size first, which a damaged header can make any number of bytes."""
    for record in records:
        if not isinstance(record, Chunk):
            yield record
            continue
        if record.compression == "zstd":
            data = zstandard.ZstdDecompressor().decompressobj().decompress(record.data)
            if len(data) != record.uncompressed_size:
                raise ValueError(
                    f"a chunk decompresses to {len(data)} bytes, its header says {record.uncompressed_size}"
                )
            record = dataclasses.replace(record, compression="", data=data)
        yield from breakup_chunk(record, validate_crc=True)


class _FileBounded:
    """A binary file whose ``read(n)`` never asks for more than the file holds: the mcap package reads a length
    field and then that many bytes, which a damaged field can make petabytes (a ``MemoryError`` before any
    check); cut to what is left, the read comes back short and the reader reports the file as cut there."""

    def __init__(self, stream: Any, size: int) -> None:
        self._stream, self._size = stream, size

    def read(self, n: int = -1) -> bytes:
        left = max(self._size - self._stream.tell(), 0)
        return self._stream.read(left if n is None or n < 0 or n > left else n)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def read_records(path: Path, allow_truncated: bool) -> RawLog:
    """Every complete record of the file's data section; a damaged data section is an error unless
    ``allow_truncated``. The summary section only indexes the data: its records are not read into the log, and
    damage to it (a failed record or a summary CRC that does not match) is reported in ``summary_damage``."""
    try:
        size = path.stat().st_size
        stream = open(path, "rb")  # noqa: SIM115 - closed below
    except FileNotFoundError:
        raise LogError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise LogError(f"{path}: is a directory, not an MCAP file") from None
    except OSError as err:
        raise LogError(f"{path}: cannot open: {err.strerror}") from None
    raw = RawLog()
    footer: Footer | None = None
    with stream:
        if size == 0:
            raise LogError(f"{path}: empty file, not an MCAP log")
        if stream.read(8) != b"\x89MCAP0\r\n":
            raise LogError(f"{path}: not an MCAP file (it does not start with the MCAP magic bytes)")
        stream.seek(0)
        reader = StreamReader(_FileBounded(stream, size), validate_crcs=True, record_size_limit=RECORD_LIMIT,
                              emit_chunks=True)
        try:
            for record in _unchunked(reader.records):
                if isinstance(record, DataEnd | Footer):
                    raw.complete = True
                    footer = record if isinstance(record, Footer) else None
                elif raw.complete:
                    continue  # the summary section: copies of schemas and channels, indexes, statistics
                elif isinstance(record, Message):
                    raw.messages.append(record)
                elif isinstance(record, Schema):
                    raw.schemas.setdefault(record.id, record)
                elif isinstance(record, Channel):
                    raw.channels.setdefault(record.id, record)
                elif isinstance(record, Metadata):
                    raw.metadata.append(record)
                elif isinstance(record, Attachment):
                    raw.attachments.append(record)
                elif isinstance(record, Header):
                    raw.header = record
            end = stream.tell()
        except FILE_ERRORS as err:
            at = stream.tell()
            what = f"{type(err).__name__}: {err}" if str(err) else type(err).__name__
            if raw.complete:  # the data section is whole; what follows it is damaged or cut
                raw.summary_damage = f"byte {at} of {size} ({what})"
                return raw
            raw.stopped_at = f"byte {at} of {size} ({what})"
            # running out of bytes (or a record longer than the rest of the file) is a cut; anything else damage
            cut = isinstance(err, EndOfFile | struct.error | RecordLengthLimitExceeded) or at >= size
            if allow_truncated:
                pass
            elif cut:
                raise TruncatedLogError(
                    f"{path}: the log is truncated: it ends at byte {size} before its footer ({what}); its writer "
                    f"was probably killed. `deck-sim log recover {path}` writes a valid copy holding every "
                    "complete chunk"
                ) from None
            else:
                raise LogError(
                    f"{path}: the log is damaged at byte {at} of {size} ({what}). `deck-sim log recover {path}` "
                    "writes a valid copy holding every record before the damage"
                ) from None
            return raw
        if footer is not None and footer.summary_start and footer.summary_crc:
            # the CRC covers the summary section and the footer up to the CRC itself (the footer's last 4 bytes,
            # followed by the 8 magic bytes)
            crc_at = end - 8 - 4
            if not 0 < footer.summary_start <= crc_at:
                raw.summary_damage = (
                    f"the footer's summary start, byte {footer.summary_start}, lies outside the file's {size} bytes"
                )
            else:
                stream.seek(footer.summary_start)
                if zlib.crc32(stream.read(crc_at - footer.summary_start)) != footer.summary_crc:
                    raw.summary_damage = (
                        f"bytes {footer.summary_start} to {crc_at} of {size} (the summary section's CRC does not match)"
                    )
    return raw
