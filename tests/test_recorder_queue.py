"""The recorder's byte-bounded queue: what ``when_full = drop`` and ``block`` promise."""

from __future__ import annotations

import threading

from services.recorder import ByteQueue


def item(n: int, size: int = 100) -> tuple[str, bytes, int]:
    return ("k", bytes(size), n)


def test_drop_policy_refuses_when_full_and_keeps_order() -> None:
    q = ByteQueue(limit_bytes=250, block=False)
    assert q.put(item(0)) and q.put(item(1))
    assert not q.put(item(2))  # 300 > 250: dropped, the caller counts it
    assert q.bytes == 200 and len(q) == 2
    got = q.get(0.1)
    assert got is not None and got[2] == 0
    assert q.put(item(3))
    assert [q.get(0.1)[2] for _ in range(2)] == [1, 3]  # type: ignore[index]
    assert q.get(0.01) is None and q.bytes == 0


def test_an_item_larger_than_the_limit_still_fits_an_empty_queue() -> None:
    q = ByteQueue(limit_bytes=10, block=False)
    assert q.put(item(0, 1000))
    assert not q.put(item(1, 1))


def test_block_policy_waits_for_room_and_close_releases_it() -> None:
    q = ByteQueue(limit_bytes=150, block=True)
    assert q.put(item(0))
    results: list[bool] = []
    waiter = threading.Thread(target=lambda: results.append(q.put(item(1))))
    waiter.start()
    waiter.join(0.3)
    assert waiter.is_alive() and results == []  # pushing back on the producer
    assert q.get(0.1) is not None
    waiter.join(5)
    assert results == [True] and len(q) == 1
    blocked = threading.Thread(target=lambda: results.append(q.put(item(2))))
    blocked.start()
    q.close()  # a failed writer must not leave Zenoh's delivery thread waiting forever
    blocked.join(5)
    assert results == [True, False] and not q.put(item(3))
