"""XML from untrusted files, parsed by defusedxml: a DTD is refused by the parser itself, after
the bytes are decoded in whatever encoding the file declares (UTF-16 included), so an entity
bomb cannot expand and no external entity is fetched; elements nest at most MAX_DEPTH deep
(no data format nests beyond ~8), and the tree's elements are charged against the memory limit
(engine/limits.py) as they are made.

The document is fed to expat in pieces of FEED_BYTES (a file is read as it is fed, never held
whole), and a token that runs beyond MAX_TOKEN_BYTES is refused: expat 2.5 scans an unfinished
token again with each piece (a 1 GiB attribute took 10 minutes), and where it stands is its own
byte index, so the check sees tokens in any encoding. A start tag with its attributes, a comment
or a processing instruction is one token; text and CDATA are not (expat hands them on as they
come). The longest token in the shared data is a few hundred bytes.

Both readers parse through here (io/nektar/xmlfile.py, io/vtu/vtkfile.py) and turn XmlRefused
and ParseError into their own errors naming the file.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET

from ..engine import limits

MAX_DEPTH = 64
MAX_TOKEN_BYTES = 16 << 20  # refusing one costs ~0.4 s (expat's rescans up to it)
FEED_BYTES = 1 << 20
# What one parsed element costs (ElementTree's node, its attribute dict, tag and text): charged
# against the memory limit as the tree grows, so a small file of millions of elements is refused.
ELEMENT_BYTES = 300
_CHARGE_EVERY = 1 << 16

ParseError = ET.ParseError


class XmlRefused(ValueError):
    """XML the readers refuse before building it: a DTD or entity declaration, deep nesting, a
    token beyond MAX_TOKEN_BYTES."""


class _Tree(ET.TreeBuilder):
    """ElementTree's builder, counting depth."""

    def __init__(self):
        super().__init__()
        self.depth = 0
        self.count = 0

    def start(self, tag, attrs):
        self.depth += 1
        self.count += 1
        if self.depth > MAX_DEPTH:
            raise XmlRefused(f"elements nest more than {MAX_DEPTH} deep; refused")
        if not self.count % _CHARGE_EVERY:  # check_bytes reports progress too
            limits.check_bytes(self.count * ELEMENT_BYTES, f"{self.count:,} XML elements or more")
        return super().start(tag, attrs)

    def end(self, tag):
        self.depth -= 1
        return super().end(tag)


def _pieces(source, size: int | None):
    """FEED_BYTES pieces of bytes, or of a binary file read as it goes (at most `size` bytes)."""
    if isinstance(source, (bytes, bytearray, memoryview)):
        view = memoryview(source)
        for start in range(0, len(view), FEED_BYTES):
            yield view[start:start + FEED_BYTES]
        return
    read = 0
    while True:
        piece = source.read(FEED_BYTES)
        if not piece:
            return
        read += len(piece)
        if size is not None and read > size:
            raise limits.UnsafeFileError("the file grew while it was read; refused")
        yield piece


def parse(source, size: int | None = None) -> ET.Element:
    """The root element of an XML document: bytes, or a binary file object read in pieces (at
    most `size` bytes, its size when opened). Raises XmlRefused (DTD, entities, nesting, a token
    beyond MAX_TOKEN_BYTES), limits.ResourceLimitError (elements beyond the memory limit),
    ParseError (not well-formed), OSError (reading the file) or ImportError (defusedxml missing)."""
    try:
        from defusedxml import DefusedXmlException
        from defusedxml.ElementTree import DefusedXMLParser
    except ImportError:
        raise ImportError("reading XML needs the defusedxml package (pip install defusedxml)") from None
    parser = DefusedXMLParser(target=_Tree(), forbid_dtd=True, forbid_entities=True, forbid_external=True)
    expat = parser.parser
    fed = 0
    try:
        for piece in _pieces(source, size):
            limits.progress()
            parser.feed(piece)
            fed += len(piece)
            if fed - max(expat.CurrentByteIndex, 0) > MAX_TOKEN_BYTES:  # expat stands at the unfinished token
                raise XmlRefused(f"an XML token (a tag with its attributes, a comment or a processing instruction) "
                                 f"runs beyond {limits.format_size(MAX_TOKEN_BYTES)} from byte "
                                 f"{max(expat.CurrentByteIndex, 0):,}; refused")
        return parser.close()
    except DefusedXmlException:
        raise XmlRefused("DOCTYPE/ENTITY declarations are refused") from None
