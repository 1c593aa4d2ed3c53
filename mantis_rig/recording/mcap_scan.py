"""Tolerant sequential scan of an MCAP file: every complete record up to the first damage.

Used for files a crash left without summary and footer, or cut mid-chunk, or corrupted. Records
are framed by (opcode, length); a record whose declared length runs past the end of the file, or
that fails to parse or to pass its chunk CRC, is where the damage starts. Nothing after it is
trusted (a corrupted length would make the rest of the framing meaningless).
"""
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
import struct

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk

from mantis_sim.errors import InputError

MAGIC = b'\x89MCAP0\r\n'
_RECORD_PREFIX = struct.Struct('<BQ')
_KNOWN_OPCODES = {int(op) for op in Opcode}
_FOOTER_RECORD_SIZE = _RECORD_PREFIX.size + 20


class NotMcapError(InputError):
    """The file is not an MCAP file at all (or is empty)."""


@dataclass
class Damage:
    """Where and how an MCAP file stops being readable."""

    file: Path
    offset: int  # byte offset of the first unreadable byte/record
    file_size: int
    problem: str

    def __str__(self):
        return (f'{self.file}: damaged at byte {self.offset} of {self.file_size}: '
                f'{self.problem}')


@dataclass
class ScanResult:
    """What a tolerant scan of one MCAP file found."""

    path: Path
    file_size: int
    header: Header = None
    schemas: dict = field(default_factory=dict)  # id -> Schema
    channels: dict = field(default_factory=dict)  # id -> Channel
    messages: list = field(default_factory=list)  # Message, in file order
    metadata: list = field(default_factory=list)  # Metadata, in file order
    data_end_seen: bool = False
    footer_seen: bool = False
    damage: Damage = None


def has_valid_tail(path):
    """True if the file ends with a footer record and the closing magic (cheap check)."""
    path = Path(path)
    size = path.stat().st_size
    if size < len(MAGIC) * 2 + _FOOTER_RECORD_SIZE:
        return False
    with open(path, 'rb') as stream:
        stream.seek(size - len(MAGIC) - _FOOTER_RECORD_SIZE)
        tail = stream.read()
    opcode, length = _RECORD_PREFIX.unpack_from(tail)
    return tail.endswith(MAGIC) and opcode == Opcode.FOOTER and length == 20


def _opcode_name(opcode):
    try:
        return Opcode(opcode).name
    except ValueError:
        return f'0x{opcode:02x}'


def _parse_body(opcode, body):
    stream = ReadDataStream(BytesIO(body))
    if opcode == Opcode.MESSAGE:
        return [Message.read(stream, len(body))]
    if opcode == Opcode.CHUNK:
        return breakup_chunk(Chunk.read(stream), validate_crc=True)
    parsers = {Opcode.HEADER: Header, Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel,
               Opcode.METADATA: Metadata, Opcode.DATA_END: DataEnd, Opcode.FOOTER: Footer}
    parser = parsers.get(opcode)
    return [] if parser is None else [parser.read(stream)]


def _collect(result, record):
    if isinstance(record, Message):
        result.messages.append(record)
    elif isinstance(record, Schema):
        result.schemas[record.id] = record
    elif isinstance(record, Channel):
        result.channels[record.id] = record
    elif isinstance(record, Metadata):
        result.metadata.append(record)
    elif isinstance(record, Header):
        result.header = record
    elif isinstance(record, DataEnd):
        result.data_end_seen = True
    elif isinstance(record, Footer):
        result.footer_seen = True


def scan_mcap(path):
    """Scan ``path`` record by record; never raises on damage, reports it in ``.damage``."""
    path = Path(path)
    size = path.stat().st_size
    result = ScanResult(path=path, file_size=size)
    with open(path, 'rb') as stream:
        magic = stream.read(len(MAGIC))
        if size == 0:
            raise NotMcapError(f'{path}: file is empty (0 bytes), no MCAP data was written')
        if magic != MAGIC[:len(magic)]:
            raise NotMcapError(f'{path}: not an MCAP file (starts with {magic[:8]!r})')
        if len(magic) < len(MAGIC):
            result.damage = Damage(path, 0, size, 'file ends inside the MCAP magic')
            return result
        offset = len(MAGIC)
        while not result.footer_seen:
            prefix = stream.read(_RECORD_PREFIX.size)
            if not prefix:
                result.damage = Damage(path, offset, size, _missing_end_problem(result))
                return result
            if len(prefix) < _RECORD_PREFIX.size:
                result.damage = Damage(path, offset, size,
                                       'file cut inside a record header (truncated)')
                return result
            opcode, length = _RECORD_PREFIX.unpack(prefix)
            name = _opcode_name(opcode)
            if opcode not in _KNOWN_OPCODES and opcode < 0x80:
                result.damage = Damage(path, offset, size,
                                       f'invalid record opcode {name} (corrupted data)')
                return result
            remaining = size - offset - _RECORD_PREFIX.size
            if length > remaining:
                result.damage = Damage(
                    path, offset, size,
                    f'{name} record declares {length} bytes but only {remaining} remain '
                    '(file cut mid-record, e.g. mid-chunk, or corrupted length)')
                return result
            body = stream.read(length)
            try:
                records = _parse_body(opcode, body)
            except Exception as exc:  # noqa: BLE001 - any parse failure is reported as damage
                result.damage = Damage(path, offset, size,
                                       f'{name} record unreadable: {type(exc).__name__}: {exc}')
                return result
            for record in records:
                _collect(result, record)
            offset += _RECORD_PREFIX.size + length
        if stream.read(len(MAGIC)) != MAGIC:
            result.damage = Damage(path, offset, size, 'footer not followed by the MCAP magic')
    return result


def _missing_end_problem(result):
    if result.data_end_seen:
        return 'file ends inside the summary section (no footer)'
    return ('file ends without summary or footer: the writer did not close it '
            '(crash or kill); records before this point are complete')
