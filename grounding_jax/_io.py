"""Result files are written whole or not at all."""

from __future__ import annotations

import json
import os
import pathlib


def atomic_write_text(path: pathlib.Path, text: str) -> None:
    """Write ``text`` to a hidden temporary beside ``path``, then rename it into place."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def pyplot():
    """matplotlib.pyplot on the headless Agg backend (imported on first use)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def write_figure(out: pathlib.Path, name: str, payload: dict, fig) -> None:
    """``out/<name>.json`` (the figure's data) and ``out/<name>.png``, each written whole;
    the figure is closed."""
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / f"{name}.json", json.dumps(payload, indent=2) + "\n")
    tmp_png = out / f".{name}.tmp.png"
    fig.savefig(tmp_png, dpi=110, bbox_inches="tight")
    os.replace(tmp_png, out / f"{name}.png")
    pyplot().close(fig)
