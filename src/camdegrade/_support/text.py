"""Text for a terminal: names that come from files (profile names and descriptions, file names) shown so that none
can move the cursor, clear the screen, reverse the text's direction or start a line of its own."""

from __future__ import annotations

import os


def printable(text: object) -> str:
    """``str(text)`` with every character that is not printable (control characters such as ESC and newline, format
    characters such as the right-to-left override, line and paragraph separators, lone surrogates of undecodable
    file names) written as its Python escape: ``"a\\x1b[2Jb"``, ``"a\\nb"``, ``"\\u202e"``. Printable text, spaces
    and letters of every script included, is unchanged.

    Examples:
        >>> printable("cam\\x1b[2J\\nfake line")
        'cam\\\\x1b[2J\\\\nfake line'
    """
    text = str(text)
    if text.isprintable():
        return text
    return "".join(char if char.isprintable() or char == " " else _escape(char) for char in text)


def printable_lines(text: object) -> str:
    """Each line of ``text`` made :func:`printable`; the line breaks themselves are kept."""
    return "\n".join(printable(line) for line in str(text).split("\n"))


def _escape(char: str) -> str:
    code = ord(char)
    if code < 0x100:
        return {"\n": "\\n", "\r": "\\r", "\t": "\\t"}.get(char, f"\\x{code:02x}")
    return f"\\u{code:04x}" if code < 0x10000 else f"\\U{code:08x}"


def not_an_option(path: str) -> str:
    """``path`` as an argument of a suggested command line: prefixed ``./`` when it starts with ``-``, so that the
    command does not read it as an option (quote the whole line with :func:`shlex.join`)."""
    return os.path.join(".", path) if path.startswith("-") else path
