"""A part run on its own thread (core.beside): its result, its errors, its cancelling, its
compile seconds told apart, an interrupt held back on it reaching the main thread, and
figures drawn on two threads at once."""

from __future__ import annotations

import os
import signal
import threading
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from grounding_jax.core import beside, compiles, guard
from grounding_jax.core.io import pyplot


def test_the_result_comes_back_and_the_thread_compiles_are_its_own():
    compiles.install()

    def part(n: int, stop):
        return float(jax.jit(lambda x: jnp.sin(x) * n)(jnp.float32(1.0)))

    job = beside.Beside("part", part, 3)
    mine = compiles.thread_seconds()
    assert job.result() == pytest.approx(3 * np.sin(1.0), rel=1e-6)
    assert job.wall_s > 0 and job.compile_s > 0  # it traced, lowered and built its jit
    assert compiles.thread_seconds() == mine  # none of it counted on this thread


def test_an_error_in_the_part_is_raised_where_the_result_is_asked_for():
    def part(stop):
        raise ValueError("bad field")

    with pytest.raises(ValueError, match="bad field"):
        beside.Beside("part", part).result()


def test_an_error_around_the_part_stops_it_at_its_next_check_and_waits():
    steps = []

    def part(stop):
        for i in range(1000):
            beside.check(stop)
            steps.append(i)
            time.sleep(0.005)

    with pytest.raises(RuntimeError, match="outside"):
        with beside.Beside("part", part) as job:
            time.sleep(0.05)
            raise RuntimeError("outside")
    done = len(steps)
    assert 0 < done < 1000
    assert not job._thread.is_alive()  # waited for: nothing is written after the block
    with pytest.raises(beside.Cancelled):
        job.result()


def test_an_interrupt_held_back_on_a_part_thread_lands_on_the_main_thread():
    entered, release = threading.Event(), threading.Event()

    def sealing():
        with guard.deferred():
            entered.set()
            release.wait(5)

    with guard.handle_interrupts(), pytest.raises(KeyboardInterrupt):
        t = threading.Thread(target=sealing)
        t.start()
        entered.wait(5)
        os.kill(os.getpid(), signal.SIGINT)  # held back: a file is being sealed
        time.sleep(0.05)
        release.set()
        t.join(5)
        for _ in range(200):  # the main thread's handler raises at its next bytecode
            time.sleep(0.01)


def test_figures_drawn_on_two_threads_at_once_are_each_whole(tmp_path):
    plt = pyplot()

    def draw(name: str, n: int) -> None:
        for i in range(5):
            fig, axes = plt.subplots(1, 2, figsize=(3, 2), sharey=True)
            axes[0].plot(np.arange(n) * i)
            fig.savefig(tmp_path / f"{name}{i}.png")
            plt.close(fig)

    threads = [threading.Thread(target=draw, args=(c, n)) for c, n in (("a", 10), ("b", 20))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    pngs = sorted(tmp_path.glob("*.png"))
    assert len(pngs) == 10
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in pngs)
