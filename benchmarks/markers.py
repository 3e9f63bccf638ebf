"""README table markers: find and rewrite the text between ``<!-- table:NAME -->`` and
``<!-- /table:NAME -->``.

Each marker sits alone on its line (leading spaces allowed, so a table can live inside a list
item: the rewritten body gets the opening marker's indentation). Everything outside the
markers, the marker lines included, is kept byte for byte. A marker opened twice, closed
without being opened, nested, or left open is an error naming the table.
"""

from __future__ import annotations

import re

_MARK = re.compile(r"^(?P<indent>[ \t]*)<!-- (?P<close>/?)table:(?P<name>[A-Za-z0-9_.-]+) -->[ \t]*$",
                   re.MULTILINE)


class MarkerError(ValueError):
    """The README's table markers are malformed (the message names the table)."""


def find_blocks(text: str) -> dict[str, tuple[int, int, str]]:
    """``{name: (body_start, body_end, indent)}``: character offsets of the text between the end
    of the opening marker's line and the start of the closing marker's line."""
    blocks: dict[str, tuple[int, int, str]] = {}
    open_name, open_end, open_indent = None, 0, ""
    for m in _MARK.finditer(text):
        name = m.group("name")
        if not m.group("close"):
            if open_name is not None:
                raise MarkerError(f"table {open_name!r}: not closed before table {name!r} opens "
                                  f"(line {_line(text, m.start())})")
            if name in blocks:
                raise MarkerError(f"table {name!r}: opened twice (line {_line(text, m.start())})")
            # the body starts after the newline that ends the opening marker's line
            open_name, open_indent = name, m.group("indent")
            open_end = m.end() + 1 if text[m.end():m.end() + 1] == "\n" else m.end()
        else:
            if open_name != name:
                raise MarkerError(f"table {name!r}: closing marker without an opening one "
                                  f"(line {_line(text, m.start())})")
            blocks[name] = (open_end, m.start(), open_indent)
            open_name = None
    if open_name is not None:
        raise MarkerError(f"table {open_name!r}: opening marker never closed")
    return blocks


def replace_blocks(text: str, bodies: dict[str, str]) -> str:
    """``text`` with the body of each named block replaced (a missing block is an error naming
    it). Bodies are markdown without indentation; each non-empty line gets the block's indent."""
    blocks = find_blocks(text)
    missing = [n for n in bodies if n not in blocks]
    if missing:
        raise MarkerError(f"table(s) {', '.join(sorted(missing))}: no "
                          "`<!-- table:NAME -->` ... `<!-- /table:NAME -->` markers in the README")
    out, pos = [], 0
    for name, (start, end, indent) in sorted(blocks.items(), key=lambda kv: kv[1][0]):
        if name not in bodies:
            continue
        body = bodies[name].strip("\n")
        lines = [(indent + ln if ln.strip() else "") for ln in body.split("\n")]
        out += [text[pos:start], "\n".join(lines) + "\n"]
        pos = end
    out.append(text[pos:])
    return "".join(out)


def block_text(text: str, name: str) -> str:
    """The current body of one block (indentation as in the file)."""
    blocks = find_blocks(text)
    if name not in blocks:
        raise MarkerError(f"table {name!r}: no markers in the README")
    start, end, _ = blocks[name]
    return text[start:end]


def _line(text: str, pos: int) -> int:
    return text.count("\n", 0, pos) + 1
