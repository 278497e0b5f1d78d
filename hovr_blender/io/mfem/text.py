"""MFEM's text files read under the resource policy: a cursor over the file's bytes that reads
what MFEM's own reader reads (keywords, counts, lines, blocks of numbers) and refuses, in one line
naming the file and the line, what it does not understand.

No library reads MFEM's formats (PyMFEM aborts the process on a bad file), so this is the
parser. Its bounds: the whole file is read once (its size checked against the memory limit
first), every count is checked against what the file's size can hold before anything is
allocated for it, and blocks of numbers are converted a few MB at a time (numpy, strict:
a token that is not a number is refused, never skipped).
"""
from __future__ import annotations

import re

import numpy as np

from ...engine import limits

MAX_FILE_BYTES = 8 << 30  # a .mesh or .gf; the memory limit usually binds first
CHUNK = 4 << 20  # bytes of text converted at a time
_STOP = re.compile(rb"^[ \t]*[#A-Za-z_\"]", re.M)  # where a block of numbers ends: a keyword or comment line
_TOKEN = re.compile(rb"[^ \t\r\n\f\v]*")
_INT_BYTES = b"0123456789+- \t\r\n\f\v"
_FLOAT_BYTES = _INT_BYTES + b".eE"


class MFEMError(ValueError):
    """An MFEM file this reader cannot use; the message names the file and, where known, the line."""


def shown(token: bytes | str, limit: int = 40) -> str:
    """A token as a message shows it: printable, at most `limit` characters."""
    text = token.decode("ascii", "replace") if isinstance(token, bytes) else token
    text = "".join(c if c.isprintable() else "?" for c in text)
    return repr(text if len(text) <= limit else text[:limit] + "...")


class Text:
    """A cursor over one file's bytes."""

    def __init__(self, path, what: str, head: int | None = None):
        """The whole file, or its first `head` bytes."""
        self.path = str(path)
        if head is None:
            self.data = limits.read_regular(path, what, MAX_FILE_BYTES)
        else:
            with limits.open_regular(path, what) as fh:
                self.data = fh.read(head)
        self.pos = 0

    # ------------------------------------------------------------------ messages

    def line_number(self, pos: int | None = None) -> int:
        return self.data.count(b"\n", 0, self.pos if pos is None else pos) + 1

    def error(self, message: str, pos: int | None = None) -> MFEMError:
        return MFEMError(f"{self.path}: line {self.line_number(pos)}: {message}")

    # ------------------------------------------------------------------ tokens

    def at_end(self) -> bool:
        self.skip_space()
        return self.pos >= len(self.data)

    def skip_space(self):
        data, n = self.data, len(self.data)
        while self.pos < n and data[self.pos] in b" \t\r\n\f\v":
            self.pos += 1

    def skip_comments(self):
        """Blank lines and lines starting with '#' (MFEM's skip_comment_lines)."""
        while True:
            self.skip_space()
            if self.pos < len(self.data) and self.data[self.pos:self.pos + 1] == b"#":
                end = self.data.find(b"\n", self.pos)
                self.pos = len(self.data) if end < 0 else end + 1
            else:
                return

    def word(self) -> bytes:
        """The next whitespace-delimited token (b"" at the end of the file)."""
        self.skip_space()
        m = _TOKEN.match(self.data, self.pos)
        self.pos = m.end()
        return m.group()

    def line(self) -> bytes:
        """The rest of the line after leading whitespace (MFEM: `input >> ws; getline`)."""
        self.skip_space()
        end = self.data.find(b"\n", self.pos)
        end = len(self.data) if end < 0 else end
        text = self.data[self.pos:end]
        self.pos = min(end + 1, len(self.data))
        return text.rstrip(b"\r")

    def keyword(self, *expected: str) -> str:
        """The next token, which must be one of `expected` (comment lines before it skipped)."""
        self.skip_comments()
        start = self.pos
        token = self.word()
        text = token.decode("ascii", "replace")
        if text not in expected:
            found = "the end of the file" if not token else shown(token)
            raise self.error(f"expected {' or '.join(repr(e) for e in expected)}, found {found}", start)
        return text

    def integer(self, what: str, lo: int, hi: int) -> int:
        self.skip_comments()
        start = self.pos
        token = self.word()
        if not re.fullmatch(rb"[+-]?[0-9]{1,19}", token):
            raise self.error(f"{what}: expected a whole number, found "
                             f"{'the end of the file' if not token else shown(token)}", start)
        value = int(token)
        if not lo <= value <= hi:
            raise self.error(f"{what} {value:,} is outside {lo:,}..{hi:,}", start)
        return value

    # ------------------------------------------------------------------ blocks of numbers

    def block_end(self) -> int:
        """Where the block of numbers starting here ends: at the next line that starts with a
        letter, '#' or a quote (a keyword, a comment), or at the end of the file."""
        m = _STOP.search(self.data, self.pos)
        return m.start() if m else len(self.data)

    def numbers(self, dtype, what: str, end: int | None = None) -> np.ndarray:
        """The numbers from here to `end` (default: block_end()), as a flat array; the cursor
        moves to `end`. A token that is not a number of the dtype (NaN, Inf, 1.5 for an integer)
        is refused with its line."""
        end = self.block_end() if end is None else end
        start = self.pos
        region = memoryview(self.data)[start:end]
        allowed = _INT_BYTES if np.dtype(dtype).kind == "i" else _FLOAT_BYTES
        # the bound before any allocation: a number takes at least two bytes of text
        limits.check_bytes((len(region) // 2 + 1) * np.dtype(dtype).itemsize, f"{self.path}: {what}")
        pieces, offset = [], 0
        while offset < len(region):
            limits.progress()
            stop = min(offset + CHUNK, len(region))
            while stop < len(region) and region[stop] not in b" \t\r\n\f\v":
                stop += 1  # end a chunk between tokens
            chunk = bytes(region[offset:stop])
            tokens = chunk.split()
            try:
                if chunk.translate(None, allowed):
                    raise ValueError
                if tokens:
                    pieces.append(np.array(tokens, dtype=dtype))
            except (ValueError, OverflowError):
                raise self._bad_token(chunk, start + offset, dtype, what) from None
            offset = stop
        self.pos = end
        out = np.concatenate(pieces) if pieces else np.zeros(0, dtype=dtype)
        if out.dtype.kind == "f" and not np.all(np.isfinite(out)):
            raise self.error(f"{what}: a value is NaN or Inf (out of range)", start)
        if end < len(self.data):
            token = self.data[end:end + 8].lstrip(b" \t").lower()
            if token.startswith((b"nan", b"inf", b"-nan", b"+nan", b"-inf", b"+inf")):
                raise self.error(f"{what}: a value is NaN or Inf", end)
        return out

    def _bad_token(self, chunk: bytes, offset: int, dtype, what: str) -> MFEMError:
        """The error naming the first token of `chunk` that is not a number of the dtype."""
        integer = np.dtype(dtype).kind == "i"
        allowed = _INT_BYTES if integer else _FLOAT_BYTES
        for m in re.finditer(rb"[^ \t\r\n\f\v]+", chunk):
            token = m.group()
            try:
                if token.translate(None, allowed):
                    raise ValueError
                if integer and not -2 ** 63 <= int(token) < 2 ** 63:
                    raise ValueError
                float(token)
            except ValueError:
                return self.error(f"{what}: {shown(token)} is not {'a whole number' if integer else 'a number'}",
                                  offset + m.start())
        return self.error(f"{what}: unreadable numbers", offset)
