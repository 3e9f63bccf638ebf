"""Keys name variables: ``key('x', 1)`` is the key printed ``x1``.

A key is an ``int`` (fast to hash, usable as an array index source) whose top byte holds a
character and whose low 56 bits hold an index, as in miniSAM and GTSAM's ``Symbol``.
Plain non-negative ints are valid keys too; they print as themselves.
"""

from __future__ import annotations

from .errors import FgoptError

_CHAR_SHIFT = 56
_INDEX_MASK = (1 << _CHAR_SHIFT) - 1


class Key(int):
    """An integer key with a readable ``repr`` (``x1``, ``l42``).

    Example:

    >>> k = fgopt.Key(7)
    >>> k, k.char, k.index
    (7, '', 7)
    >>> key('x', 3).char, key('x', 3).index
    ('x', 3)
    """

    __slots__ = ()

    @property
    def char(self) -> str:
        c = int(self) >> _CHAR_SHIFT
        return chr(c) if c else ""

    @property
    def index(self) -> int:
        return int(self) & _INDEX_MASK

    def __repr__(self) -> str:
        return key_str(self)

    __str__ = __repr__


def key(char: str, index: int) -> Key:
    """Make the key ``<char><index>``, e.g. ``key('x', 1)`` -> ``x1``.

    Example:

    >>> key('x', 1)
    x1
    >>> int(key('x', 1)) == (ord('x') << 56) | 1
    True
    """
    if not isinstance(char, str) or len(char) != 1 or not (0 < ord(char) < 128):
        raise FgoptError(f"key char must be one ASCII character, got {char!r}")
    index = int(index)
    if index < 0 or index > _INDEX_MASK:
        raise FgoptError(f"key index must be in [0, 2**56), got {index}")
    return Key((ord(char) << _CHAR_SHIFT) | index)


def key_char(k: int) -> str:
    c = int(k) >> _CHAR_SHIFT
    return chr(c) if c else ""


def key_index(k: int) -> int:
    return int(k) & _INDEX_MASK


def key_str(k: int) -> str:
    """``x1`` for ``key('x', 1)``; a plain int key prints as the number."""
    return f"{key_char(k)}{key_index(k)}"


def as_key(k: object) -> Key:
    """Accept a Key or a non-negative int; anything else is an error."""
    if isinstance(k, Key):
        return k
    if isinstance(k, (int,)) and not isinstance(k, bool) and k >= 0:
        return Key(k)
    try:
        import numpy as np

        if isinstance(k, np.integer) and k >= 0:
            return Key(int(k))
    except ImportError:  # pragma: no cover
        pass
    raise FgoptError(f"{k!r} is not a key: use fgopt.key('x', 1) or a non-negative int")

