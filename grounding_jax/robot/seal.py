"""``python -m grounding_jax.robot.seal DIR``: seal trained modules saved before checksums were
saved with them (see `grounding_jax.robot.trained.seal`); ``load`` refuses unsealed ones."""

from __future__ import annotations

import argparse
import sys

from grounding_jax.core import guard
from grounding_jax.core.checkpoint import CheckpointError
from grounding_jax.robot import trained


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m grounding_jax.robot.seal", description=__doc__)
    ap.add_argument("directory", help="a modules folder saved by train.py or trained.save")
    args = ap.parse_args(argv)
    try:
        trained.seal(args.directory)
    except (CheckpointError, guard.FolderBusyError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"sealed {args.directory}: its files and arrays are checked on every load from now")
    return 0


if __name__ == "__main__":
    sys.exit(main())
