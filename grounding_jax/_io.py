"""Result files are written whole or not at all."""

from __future__ import annotations

import os
import pathlib


def atomic_write_text(path: pathlib.Path, text: str) -> None:
    """Write ``text`` to a hidden temporary beside ``path``, then rename it into place."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)
