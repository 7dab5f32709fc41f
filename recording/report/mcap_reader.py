"""``run.mcap`` read as untrusted data: records in file order, chunks opened within bounds.

A recording may come from anywhere (``objective report DIR`` on a directory someone sent), so
reading it costs memory and time bounded by the file's size, never by what the file declares:

- a chunk may declare at most ``ReadLimits.max_chunk_bytes`` uncompressed (checked before it is
  opened), and is never decompressed past what it declares (a zstd frame that claims one size and
  expands to another is refused);
- the chunks together may expand to at most ``ReadLimits.expansion`` times the file's size (plus
  one chunk's worth): work linear in the file, whatever it holds;
- a chunk holds schemas, channels and messages only, each within the chunk: anything else is
  refused at once instead of being skipped a few bytes at a time;
- zstd and uncompressed chunks are read (what the recorder writes); other compressions are refused.

Each refusal is an ``ObjectiveError`` naming the file, the chunk's offset and the numbers. Which
message types are decoded afterwards is ``recording.report.data``'s allow-list: nothing here
imports anything a schema names.
"""
from __future__ import annotations

from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import BinaryIO, Iterator

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import RecordLengthLimitExceeded
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, McapRecord, Message, Schema
from mcap.stream_reader import StreamReader

from runtime.errors import ObjectiveError

MAX_CHUNK_BYTES = 64 << 20
"""The recorder's chunks hold about 1 MiB (more only for one message larger than that, e.g. a big
camera frame); 64 MiB leaves room for any frame a camera sends."""
EXPANSION = 1000
"""The recorder's chunks expand 5 to 10 times (zstd, measured on stack_cubes.xml recordings);
a zstd bomb expands tens of thousands of times."""
RECORD_OVERHEAD = 4096
"""What a chunk record holds besides its data (times, sizes, the compression's name)."""
_CHUNK_RECORDS = {Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel, Opcode.MESSAGE: Message}


@dataclass(frozen=True)
class ReadLimits:
    max_chunk_bytes: int = MAX_CHUNK_BYTES
    """The most a chunk may declare uncompressed."""
    expansion: float = EXPANSION
    """The most all chunks together may expand, as a multiple of the file's size (one chunk of
    ``max_chunk_bytes`` is allowed on top)."""


def records(stream: BinaryIO, path: Path, file_bytes: int, limits: ReadLimits = ReadLimits()) -> Iterator[McapRecord]:
    """The records of the MCAP file open in ``stream`` (``file_bytes`` long), in file order, with
    each chunk's records in its place; ``mcap``'s EndOfFile or struct.error where it is cut short."""
    budget = limits.max_chunk_bytes + limits.expansion * file_bytes
    reader = StreamReader(stream, emit_chunks=True, record_size_limit=limits.max_chunk_bytes + RECORD_OVERHEAD)
    chunks = 0
    try:
        for record in reader.records:
            if isinstance(record, Chunk):
                chunks += 1
                budget -= record.uncompressed_size
                yield from chunk_records(record, f"{path}: chunk {chunks}", limits, budget < 0)
            else:
                yield record
    except RecordLengthLimitExceeded as err:
        # mcap's exception keeps the record's length in its message only ("... has length N ...").
        raise ObjectiveError(f"{path}: a record after chunk {chunks} is over the "
                             f"{limits.max_chunk_bytes + RECORD_OVERHEAD} bytes a recording's record may have ({err}): "
                             "not read") from None


def chunk_records(chunk: Chunk, where: str, limits: ReadLimits, over_budget: bool = False) -> list[McapRecord]:
    """The schemas, channels and messages of ``chunk``; ObjectiveError (naming ``where``) for a
    chunk over the limits or not what a recorder writes."""
    declared = chunk.uncompressed_size
    if declared > limits.max_chunk_bytes:
        raise ObjectiveError(f"{where} declares {declared} bytes uncompressed, over the {limits.max_chunk_bytes} "
                             "a recording's chunk may have: not read")
    if over_budget:
        raise ObjectiveError(f"{where} would expand the file's chunks to more than {limits.expansion:g} times the "
                             "file's size: not read (a compression bomb, not a recording)")
    data = _decompressed(chunk, where)
    stream = ReadDataStream(BytesIO(data))
    found: list[McapRecord] = []
    while stream.count < len(data):
        try:
            opcode, length = stream.read1(), stream.read8()
        except Exception:
            raise ObjectiveError(f"{where}: a record is cut short at byte {stream.count} of the chunk") from None
        kind = _CHUNK_RECORDS.get(opcode)  # type: ignore[call-overload]
        if kind is None or length > len(data) - stream.count:
            what = f"opcode {opcode:#04x}" if kind is None else f"a record of {length} bytes"
            raise ObjectiveError(f"{where} holds {what} at byte {stream.count - 9} of {len(data)}: not a recording's chunk")
        start = stream.count
        try:
            found.append(kind.read(stream, length) if kind is Message else kind.read(stream))
        except Exception:
            raise ObjectiveError(f"{where}: a record at byte {start - 9} cannot be read") from None
        if stream.count - start != length:
            raise ObjectiveError(f"{where}: a record at byte {start - 9} is not {length} bytes long as it declares")
    return found


def _decompressed(chunk: Chunk, where: str) -> bytes:
    """The chunk's records, never more than the size it declares."""
    declared = chunk.uncompressed_size
    if chunk.compression == "":
        data = chunk.data
    elif chunk.compression == "zstd":
        data = b""
        try:
            with zstandard.ZstdDecompressor().stream_reader(chunk.data, read_across_frames=True) as reader:
                parts = []
                got = 0
                while got <= declared:
                    part = reader.read(declared + 1 - got)
                    if not part:
                        break
                    parts.append(part)
                    got += len(part)
                data = b"".join(parts)
        except zstandard.ZstdError as err:
            raise ObjectiveError(f"{where} cannot be decompressed: {err}") from None
    else:
        raise ObjectiveError(f"{where} is compressed with '{chunk.compression}': a recording's chunks are zstd "
                             "or uncompressed")
    if len(data) != declared:
        more = "more than" if len(data) > declared else "less than"
        raise ObjectiveError(f"{where} decompresses to {more} the {declared} bytes it declares: not read")
    return data


def messages(stream: BinaryIO, path: Path, file_bytes: int,
             limits: ReadLimits = ReadLimits()) -> Iterator[tuple[Schema | None, Channel, Message]]:
    """(schema, channel, message) for every message, in file order (``records``); a message on a
    channel no record defined is refused."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    for record in records(stream, path, file_bytes, limits):
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            channel = channels.get(record.channel_id)
            if channel is None:
                raise ObjectiveError(f"{path}: a message on channel {record.channel_id}, which no record defines")
            yield schemas.get(channel.schema_id), channel, record
