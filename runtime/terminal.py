"""Text for the user's terminal, from anywhere (a robot's packets, a recording, a file): shown printable."""
from __future__ import annotations


def printable(text: str) -> str:
    """``text`` with every character that does not print (a newline, a carriage return, an escape sequence's ESC,
    C1 controls) as ``\\xNN``: raw, such text could add lines or drive the terminal (clear the screen, rewrite a
    line)."""
    return "".join(c if c.isprintable() else f"\\x{ord(c):02x}" for c in text)
