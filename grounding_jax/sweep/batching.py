"""What the sweep runner and the searches share: sharding a batch, padding it, finding its
non-finite runs, chunk ends, resuming from a checkpoint, assembling the groups' results and
the memory a batch may take."""

from __future__ import annotations

import os
import sys
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.core.checkpoint import Checkpointer


def batch_sharding(batch: int):
    """(sharding of a leading batch axis over all local devices, padding rows needed)."""
    devices = jax.local_devices()
    mesh = jax.sharding.Mesh(np.asarray(devices), ("batch",))
    return (jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("batch")),
            (-batch) % len(devices))


def pad_rows(tree, pad: int):
    """``tree`` with its first row repeated ``pad`` times at the end of every batched leaf
    (so that the batch divides among the devices)."""
    return jax.tree.map(lambda x: jnp.concatenate([x, jnp.repeat(x[:1], pad, 0)])
                        if pad and jnp.ndim(x) else x,
                        tree)


def finite_rows(tree, batch: int) -> np.ndarray:
    """Per row: every float leaf of the tree finite."""
    ok = np.ones(batch, bool)
    for leaf in jax.tree.leaves(tree):
        a = np.asarray(leaf)
        if np.issubdtype(a.dtype, np.floating):
            ok &= np.isfinite(a.reshape(batch, -1)).all(1)
    return ok


def restore_to_resume(ck: Checkpointer, like: Any) -> tuple[int, Any] | None:
    """The newest intact step of a group (a damaged newer one is set aside, said on stderr),
    or None when the group has no step yet."""
    found = ck.restore_latest(like, fallback=True)
    if found is not None:
        for where in ck.set_aside_after(found[0]):
            print(f"warning: resuming from step {found[0]}; the damaged step was moved to "
                  f"{where}", file=sys.stderr, flush=True)
        # said whether or not a progress bar shows it: where a resumed run picks up
        print(f"note: resuming {ck.directory} from its step {found[0]} (AL: the episodes "
              "done)", file=sys.stderr, flush=True)
    return found


def chunk_stops(episodes: int, chunk: int) -> list[int]:
    """Chunk ends: equal chunks of the largest divisor of ``episodes`` that is <= ``chunk``
    (one compiled shape), unless that divisor is under half of ``chunk`` -- then chunks of
    ``chunk`` and a shorter last one (a second compile)."""
    size = max(d for d in range(1, min(chunk, episodes) + 1) if episodes % d == 0)
    if size < min(chunk, episodes) / 2:
        size = chunk
    return list(range(size, episodes, size)) + [episodes]


def assemble(results: list[dict], n_rows: int) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The groups' metrics in one array per metric (row ``point * seeds + seed``). Groups of
    other run lengths (a grid over a static length field) give curves of other lengths: the
    shorter ones are padded with NaN."""
    metrics = {}
    for k in results[0]["metrics"]:
        parts = [np.asarray(r["metrics"][k]) for r in results]
        shape = tuple(max(d) for d in zip(*(a.shape[1:] for a in parts), strict=True))
        ragged = any(a.shape[1:] != shape for a in parts)
        dtype = np.result_type(parts[0].dtype, np.float32) if ragged else parts[0].dtype
        arr = np.full((n_rows, *shape), np.nan, dtype) if ragged else np.zeros(
            (n_rows, *shape), dtype)
        for r, a in zip(results, parts, strict=True):
            arr[(r["rows"], *(slice(0, d) for d in a.shape[1:]))] = a
        metrics[k] = arr
    finite = np.zeros(n_rows, bool)
    for r in results:
        finite[r["rows"]] = r["finite"]
    return metrics, finite


#: the share of the memory available that one batch's estimate may take
MEMORY_SHARE = 0.7


def memory_budget() -> tuple[int, str]:
    """(bytes a batch may take, what they are): the local accelerators' memory limit, or on
    a CPU the memory this machine has available now (``MemAvailable``)."""
    devices = jax.local_devices()
    if devices[0].platform != "cpu":
        stats = devices[0].memory_stats() or {}
        if stats.get("bytes_limit"):
            return (int(stats["bytes_limit"]) * len(devices),
                    f"the memory of {len(devices)} {devices[0].platform} device(s)")
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024, "the memory available on this machine"
    except OSError:
        pass
    return (os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"),
            "this machine's memory")


def gigabytes(n: float) -> str:
    """``n`` bytes as a short figure (``"1.2 GB"``, ``"340 MB"``, ``"250 kB"``)."""
    if n >= 1e9:
        return f"{n / 1e9:.1f} GB"
    return f"{n / 1e6:.0f} MB" if n >= 1e6 else f"{n / 1e3:.0f} kB"
