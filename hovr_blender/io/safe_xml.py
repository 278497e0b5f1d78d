"""XML from untrusted files, parsed by defusedxml: a DTD is refused by the parser itself, after
the bytes are decoded in whatever encoding the file declares (UTF-16 included), so an entity
bomb cannot expand and no external entity is fetched; and elements nest at most MAX_DEPTH deep
(no data format nests beyond ~8), and the tree's elements are charged against the memory limit
(engine/limits.py) as they are made.

Both readers parse through here (io/nektar/xmlfile.py, io/vtu/vtkfile.py) and turn XmlRefused
and ParseError into their own errors naming the file.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET

from ..engine import limits

MAX_DEPTH = 64
# What one parsed element costs (ElementTree's node, its attribute dict, tag and text): charged
# against the memory limit as the tree grows, so a small file of millions of elements is refused.
ELEMENT_BYTES = 300
_CHARGE_EVERY = 1 << 16

ParseError = ET.ParseError


class XmlRefused(ValueError):
    """XML the readers refuse before building it: a DTD or entity declaration, deep nesting."""


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
        if not self.count % _CHARGE_EVERY:
            limits.check_bytes(self.count * ELEMENT_BYTES, f"{self.count:,} XML elements or more")
        return super().start(tag, attrs)

    def end(self, tag):
        self.depth -= 1
        return super().end(tag)


def parse(raw: bytes) -> ET.Element:
    """The root element of an XML document. Raises XmlRefused (DTD, entities, nesting),
    limits.ResourceLimitError (elements beyond the memory limit), ParseError (not well-formed)
    or ImportError (defusedxml missing)."""
    try:
        from defusedxml import DefusedXmlException
        from defusedxml.ElementTree import DefusedXMLParser
    except ImportError:
        raise ImportError("reading XML needs the defusedxml package (pip install defusedxml)") from None
    parser = DefusedXMLParser(target=_Tree(), forbid_dtd=True, forbid_entities=True, forbid_external=True)
    try:
        parser.feed(raw)
        return parser.close()
    except DefusedXmlException:
        raise XmlRefused("DOCTYPE/ENTITY declarations are refused") from None
