"""Objective-supplied text made safe for a terminal: ``printable``, and kept short: ``bounded``.

Names, messages and reasons come from XML files someone else wrote. Printed raw, a control
character (an ANSI escape sequence, a carriage return, a newline) or a bidirectional override
(U+202E makes ``gpj.exe`` read as ``exe.jpg``) rewrites what the user sees. ``printable``
replaces every such character with its Python escape (``\\x1b``, ``\\u202e``, ``\\n``), so the
text reads the same in every terminal and shows what the file really holds. The CLI passes
every piece of Objective-supplied text through it before printing (the log handlers too); JSON
output needs no escaping (``json.dumps`` escapes non-ASCII).

Text from a policy or a file can also be huge (a 5 MB error message). ``printable`` prints at most
``MAX_PRINTED_CHARS`` characters of it, saying how many it cut; ``bounded`` is that cut alone,
for messages kept in a summary (ExecutePolicy's status message, the ``--json`` reason).
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
MAX_PRINTED_CHARS = 4096
"""The most characters of one message, name or log line printed (or kept, ``bounded``)."""


def _escape(char: str) -> str:
    if char in _NAMED:
        return _NAMED[char]
    code = ord(char)
    if code < 0x100:
        return f"\\x{code:02x}"
    if code < 0x10000:
        return f"\\u{code:04x}"
    return f"\\U{code:08x}"


def bounded(text: str, limit: int = MAX_PRINTED_CHARS) -> str:
    """``text`` cut to its first ``limit`` characters, ending with how many were cut."""
    if len(text) <= limit:
        return text
    return f"{text[:limit]}... ({len(text) - limit} characters cut)"


def printable(text: object, limit: int = MAX_PRINTED_CHARS) -> str:
    """``text`` (anything, as ``str``) cut to ``limit`` characters (``bounded``), with control,
    format and separator characters escaped."""
    text = bounded(str(text), limit)
    if text.isprintable():  # the common case: nothing to do
        return text
    return "".join(_escape(c) if unicodedata.category(c) in _ESCAPED_CATEGORIES else c for c in text)
