"""Objective-supplied text made safe for a terminal: ``printable``.

Names, messages and reasons come from XML files someone else wrote. Printed raw, a control
character (an ANSI escape sequence, a carriage return, a newline) or a bidirectional override
(U+202E makes ``gpj.exe`` read as ``exe.jpg``) rewrites what the user sees. ``printable``
replaces every such character with its Python escape (``\\x1b``, ``\\u202e``, ``\\n``), so the
text reads the same in every terminal and shows what the file really holds. The CLI passes
every piece of Objective-supplied text through it before printing; JSON output needs nothing
(``json.dumps`` escapes non-ASCII).
"""
from __future__ import annotations

import unicodedata

_ESCAPED_CATEGORIES = frozenset({
    "Cc",  # C0/C1 controls: ESC, CR, LF, BEL, backspace, ...
    "Cf",  # format characters: bidi embeddings/overrides/isolates, zero-width joiners, ...
    "Zl",  # line separator
    "Zp",  # paragraph separator
    "Cs",  # lone surrogates (undecodable bytes kept by surrogateescape)
})
_NAMED = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}


def _escape(char: str) -> str:
    if char in _NAMED:
        return _NAMED[char]
    code = ord(char)
    if code < 0x100:
        return f"\\x{code:02x}"
    if code < 0x10000:
        return f"\\u{code:04x}"
    return f"\\U{code:08x}"


def printable(text: object) -> str:
    """``text`` (anything, as ``str``) with control, format and separator characters escaped."""
    text = str(text)
    if text.isprintable():  # the common case: nothing to do
        return text
    return "".join(_escape(c) if unicodedata.category(c) in _ESCAPED_CATEGORIES else c for c in text)
