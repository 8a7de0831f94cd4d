"""The work queue's per-key turns and bounds (issue 64, item 4), on a real one-thread executor with jobs that sleep:
another key's job waits for the running job (or slice of one) only, not for a burst; the bound refuses the key that
floods; two keys that keep jobs waiting get about equal thread time whatever their jobs' lengths."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import pytest

from service.errors import ServiceError
from service.key_turns import CREDIT_S, KeyTurns
from service.work_queue import Continue, WorkQueue


def _job(log: list[str], name: str, seconds: float) -> Callable[[], str]:
    def run() -> str:
        log.append(name)
        time.sleep(seconds)
        return name

    return run


def test_a_quiet_keys_job_waits_for_the_running_job_only_and_the_flooding_key_is_refused():
    async def main() -> None:
        with ThreadPoolExecutor(1) as pool:
            queue = WorkQueue(pool, threads=1, limit=4)
            log: list[str] = []
            burst = [asyncio.create_task(queue.run(_job(log, f"b{i}", 0.05), owner="b")) for i in range(5)]
            await asyncio.sleep(0.01)  # b0 runs, four of b wait: b's part of the queue is full
            with pytest.raises(ServiceError) as refused:
                await queue.run(_job(log, "b5", 0.05), owner="b")
            assert refused.value.code == "overloaded" and "of this API key" in refused.value.message
            assert int(refused.value.headers["Retry-After"]) >= 1
            assert queue.waiting == 4 and queue.waiting_of("b") == 4
            quiet = asyncio.create_task(queue.run(_job(log, "a0", 0.01), owner="a"))  # not refused: a's own part
            await asyncio.gather(quiet, *burst)
            assert log == ["b0", "a0", "b1", "b2", "b3", "b4"]
            assert queue.waiting == 0 and queue.running == 0

    asyncio.run(main())


def test_without_keys_the_queue_is_first_come_first_served_with_one_bound():
    async def main() -> None:
        with ThreadPoolExecutor(1) as pool:
            queue = WorkQueue(pool, threads=1, limit=2)
            log: list[str] = []
            jobs = [asyncio.create_task(queue.run(_job(log, f"j{i}", 0.02))) for i in range(3)]
            await asyncio.sleep(0.005)
            with pytest.raises(ServiceError) as refused:
                await queue.run(_job(log, "late", 0.01))
            assert refused.value.code == "overloaded" and "of this API key" not in refused.value.message
            await asyncio.gather(*jobs)
            assert log == ["j0", "j1", "j2"]

    asyncio.run(main())


@pytest.mark.alone  # timed
def test_two_busy_keys_get_about_equal_thread_time_whatever_their_job_lengths():
    began = time.monotonic()
    runs: list[tuple[str, float, float]] = []  # owner, when its job started, how long it held the thread

    def job(owner: str, seconds: float) -> None:
        runs.append((owner, time.monotonic() - began, seconds))
        time.sleep(seconds)

    async def main() -> None:
        with ThreadPoolExecutor(1) as pool:
            queue = WorkQueue(pool, threads=1, limit=100)

            async def loop(owner: str, seconds: float) -> None:
                while time.monotonic() - began < 1.6:
                    await queue.run(job, owner, seconds, owner=owner)

            # Two jobs of each key at a time, so that each always has one waiting.
            await asyncio.gather(*(loop(k, s) for k, s in (("short", 0.01), ("long", 0.05)) for _ in range(2)))

    asyncio.run(main())
    # After the first key's head start (a key that joins is given up to CREDIT_S), in turn.
    window = (CREDIT_S + 0.2, 1.5)
    used = {k: sum(s for o, t, s in runs if o == k and window[0] <= t < window[1]) for k in ("short", "long")}
    print(f"thread time from {window[0]:.2f} to {window[1]} s: {used}")
    assert abs(used["short"] - used["long"]) <= 2 * 0.05 + 0.01, used


def test_close_answers_every_keys_waiting_jobs():
    async def main() -> None:
        with ThreadPoolExecutor(1) as pool:
            queue = WorkQueue(pool, threads=1, limit=4)
            running = asyncio.create_task(queue.run(time.sleep, 0.1, owner="a"))
            waiting = [asyncio.create_task(queue.run(time.sleep, 0.1, owner=k)) for k in ("a", "b", "b")]
            await asyncio.sleep(0.01)
            assert queue.close() == 3
            for task in waiting:
                with pytest.raises(ServiceError) as err:
                    await task
                assert err.value.code == "shutting_down"
            await running

    asyncio.run(main())


def test_key_turns_least_used_first_a_returning_key_within_the_credit():
    turns = KeyTurns(credit_s=0.25)
    assert turns.first([]) is None
    turns.charge("b", 2.0)
    assert turns.first(["b", "a"]) == "a" and turns.used["a"] == pytest.approx(1.75)  # joins at the floor
    turns.charge("a", 0.3)  # a: 2.05, b: 2.0
    assert turns.first(["b", "a"]) == "b"
    assert turns.first(["a", "c"]) == "c" and turns.used["c"] == pytest.approx(1.8)  # a new key at the floor
    turns.tidy(["a"])  # c holds the floor: forgotten; b, busy a moment ago, is kept with what it used
    assert set(turns.used) == {"a", "b"} and turns.first(["a", "b"]) == "b"
    with pytest.raises(ValueError):
        turns.charge("a", -1.0)


def _sliced(log: list[str], name: str, slices: int, seconds: float) -> Callable[[], object]:
    """A job of ``slices`` slices of ``seconds`` each, given back to the queue between them (:class:`Continue`)."""

    def part(i: int) -> object:
        log.append(f"{name}.{i}")
        time.sleep(seconds)
        return Continue(part, (i + 1,)) if i + 1 < slices else name

    return lambda: part(0)


def test_a_long_job_in_slices_lets_another_keys_job_run_between_them_and_keeps_its_own_keys_order():
    async def main() -> None:
        with ThreadPoolExecutor(1) as pool:
            queue = WorkQueue(pool, threads=1, limit=4)
            log: list[str] = []
            long = [asyncio.create_task(queue.run(_sliced(log, f"b{i}", 4, 0.03), owner="b")) for i in range(2)]
            await asyncio.sleep(0.04)  # b0's first slice has run, its second is under way
            quiet = asyncio.create_task(queue.run(_job(log, "a0", 0.01), owner="a"))
            assert await asyncio.gather(quiet, *long) == ["a0", "b0", "b1"]
            # a0 waits for one slice, not for b0's four; b1 starts only when b0 has ended (one key's jobs in order).
            assert log.index("a0") <= 3 and log.index("b1.0") == log.index("b0.3") + 1, log
            assert queue.running == 0 and queue.waiting == 0

    asyncio.run(main())


# Cancelled while waiting to start; during its first slice; with its next slice queued behind key c's job.
@pytest.mark.parametrize("cancel_at_s", [0.01, 0.055, 0.08])
@pytest.mark.alone  # timed
def test_a_sliced_job_whose_caller_is_cancelled_goes_no_further_and_frees_its_slot(cancel_at_s: float):
    async def main() -> None:
        with ThreadPoolExecutor(1) as pool:
            queue = WorkQueue(pool, threads=1, limit=4)
            log: list[str] = []
            began = time.monotonic()
            a0 = asyncio.create_task(queue.run(_job(log, "a0", 0.04), owner="a"))  # 0 - 0.04
            sliced = asyncio.create_task(queue.run(_sliced(log, "b0", 5, 0.03), owner="b"))  # from 0.04, 30 ms slices
            await asyncio.sleep(0.05)
            c0 = asyncio.create_task(queue.run(_job(log, "c0", 0.02), owner="c"))  # new key: before b0's next slice
            await asyncio.sleep(max(0.0, cancel_at_s - (time.monotonic() - began)))
            sliced.cancel()
            with pytest.raises(asyncio.CancelledError):
                await sliced
            assert await a0 == "a0" and await c0 == "c0"
            assert await asyncio.wait_for(queue.run(_job(log, "a1", 0.01), owner="a"), 2) == "a1"
            await asyncio.sleep(0.1)
            assert queue.running == 0 and queue.waiting == 0 and not queue._resuming and not queue._continuations
            assert "b0.2" not in log, log

    asyncio.run(main())
