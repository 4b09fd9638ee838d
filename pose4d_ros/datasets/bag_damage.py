"""What is wrong with a bag that its reader refused, in words a user understands.

rosbags, mcap, zstandard and sqlite3 each fail on a damaged file with messages of their own
("ord() expected a character, but string of length 0 found", "cannot fit 'int' into an
index-sized integer"), which tell a user nothing about the file. `describe` looks at the storage
file itself and says what it finds: not an MCAP file, truncated after N bytes, a damaged
header, data section, chunk, summary or footer at offset X; for SQLite bags, not an SQLite
database or a damaged one. It runs only once a read has failed, so it may read the whole file.

MCAP layout (mcap.dev/spec): magic, then records (opcode u8, length u64 LE, content), the first
a Header; Chunks hold compressed message records; DataEnd closes the data section, then the
summary section, a Footer, and the magic again.
"""

from __future__ import annotations

import mmap
import sqlite3
import struct
from pathlib import Path

MCAP_MAGIC = b'\x89MCAP0\r\n'
SQLITE_MAGIC = b'SQLite format 3\x00'
_RECORDS = {0x01: 'header', 0x02: 'footer', 0x03: 'schema', 0x04: 'channel', 0x05: 'message',
            0x06: 'chunk', 0x07: 'message index', 0x08: 'chunk index', 0x09: 'attachment',
            0x0A: 'attachment index', 0x0B: 'statistics', 0x0C: 'metadata',
            0x0D: 'metadata index', 0x0E: 'summary offset', 0x0F: 'data end'}


def storage_files(bag: Path) -> list[Path]:
    """The bag directory's storage files (.mcap, .db3)."""
    return sorted(p for p in bag.iterdir() if p.suffix in ('.mcap', '.db3'))


def describe(bag: Path) -> str:
    """What is wrong with the bag directory `bag`, naming its storage file, e.g.
    'x/run.mcap: truncated after 8 bytes (no record after the magic)'."""
    files = storage_files(bag) if bag.is_dir() else [bag]
    if bag.is_dir() and (problem := _metadata_problem(bag / 'metadata.yaml')):
        return f'{bag / "metadata.yaml"}: {problem}'
    if not files:
        return f'{bag}: no storage file (.mcap or .db3) in the bag directory'
    for file in files:
        problem = (_mcap_problem(file) if file.suffix == '.mcap' else _sqlite_problem(file))
        if problem:
            return f'{file}: {problem}'
    return (f'{files[0]}: damaged (its structure looks whole, but a record inside does not '
            'decode)')


def _metadata_problem(file: Path) -> str | None:
    import yaml

    try:
        info = yaml.safe_load(file.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return 'damaged (not readable YAML)'
    if not isinstance(info, dict) or not isinstance(
            info.get('rosbag2_bagfile_information'), dict):
        return 'damaged (no rosbag2_bagfile_information in it)'
    return None


def _mcap_problem(file: Path) -> str | None:
    size = file.stat().st_size
    if size == 0:
        return 'empty file (0 bytes), not an MCAP bag'
    with file.open('rb') as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
        if not bytes(data[:8]).startswith(MCAP_MAGIC[:min(size, 8)]):
            return 'not an MCAP file (it does not start with the MCAP magic bytes)'
        if size < 8:
            return f'truncated after {size} bytes (inside the MCAP magic)'
        return _walk(data, size)


def _walk(data: mmap.mmap, size: int) -> str | None:
    """The first problem met walking the records from the start, or None."""
    whole = size >= 16 and data[size - 8:size] == MCAP_MAGIC
    end = size - 8 if whole else size
    pos, section = 8, 'header'
    while pos < end:
        if pos + 9 > end:
            return _cut(whole, size, pos, section)
        op = data[pos]
        length = int.from_bytes(data[pos + 1:pos + 9], 'little')
        name = _RECORDS.get(op)
        if name is None or (pos == 8 and op != 0x01):
            return (f'damaged {section} at offset {pos} (not an MCAP record there: opcode '
                    f'0x{op:02x})')
        if pos + 9 + length > end:
            if whole:
                return (f'damaged {section} at offset {pos} (its {name} record claims '
                        f'{length} bytes, past the end of the file)')
            return _cut(whole, size, pos, section)
        if op == 0x06 and (problem := _chunk_problem(data[pos + 9:pos + 9 + length])):
            return f'damaged chunk at offset {pos} ({problem})'
        pos += 9 + length
        section = ('summary' if op == 0x0F or section == 'summary' else
                   'data section' if section == 'header' else section)
        if op == 0x02:  # the footer: only the closing magic may follow
            if pos != end:
                return f'damaged footer at offset {pos - 9 - length} (bytes after it)'
            return None if whole else _cut(whole, size, pos, section)
    return _cut(whole, size, pos, section)


def _cut(whole: bool, size: int, pos: int, section: str) -> str:
    if pos == 8 and not whole:
        return f'truncated after {size} bytes (nothing whole after the MCAP magic)'
    if whole:
        return f'damaged {section} at offset {pos} (the records stop before the footer)'
    return (f'truncated after {size} bytes (cut in the {section}, the last whole record ends '
            f'at offset {pos}; a recording that did not finish, or a partial copy)')


def _chunk_problem(chunk: bytes) -> str | None:
    """Why a chunk record's content does not hold its messages, or None."""
    try:
        _, _, uncompressed_size, crc, n = struct.unpack_from('<QQQII', chunk, 0)
        compression = chunk[32:32 + n].decode()
        (length,) = struct.unpack_from('<Q', chunk, 32 + n)
        body = chunk[40 + n:40 + n + length]
    except (struct.error, UnicodeDecodeError):
        return 'its fields do not parse'
    if len(body) != length:
        return f'its data claim {length} bytes, the record holds {len(body)}'
    try:
        raw = _decompress(body, compression, uncompressed_size)
    except ValueError as exc:
        return str(exc)
    except Exception:  # the codec's own error on damaged data
        return f'its {compression} data do not decompress'
    if len(raw) != uncompressed_size:
        return f'it decompresses to {len(raw)} bytes, not the {uncompressed_size} it says'
    from binascii import crc32

    if crc and crc32(raw) != crc:
        return 'its data fail their checksum'
    return None


def _decompress(body: bytes, compression: str, size: int) -> bytes:
    if compression == '':
        return body
    if compression == 'zstd':
        import zstandard

        return zstandard.ZstdDecompressor().decompress(body, max_output_size=size)
    if compression == 'lz4':
        import lz4.frame

        return lz4.frame.decompress(body)
    raise ValueError(f'an unknown compression {compression[:20]!r}')


def _sqlite_problem(file: Path) -> str | None:
    size = file.stat().st_size
    if size == 0:
        return 'empty file (0 bytes), not an SQLite bag'
    with file.open('rb') as f:
        head = f.read(16)
    if not SQLITE_MAGIC.startswith(head[:16]) or size < 16:
        return ('not an SQLite database (it does not start with the SQLite header)'
                if not SQLITE_MAGIC.startswith(head) else f'truncated after {size} bytes')
    try:
        with sqlite3.connect(f'file:{file}?mode=ro', uri=True) as db:
            rows = db.execute('PRAGMA quick_check').fetchall()
    except sqlite3.DatabaseError:
        return 'damaged SQLite database (its pages do not parse)'
    if rows != [('ok',)]:
        return f'damaged SQLite database ({len(rows)} problem(s) found by its integrity check)'
    return None
