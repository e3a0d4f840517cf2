"""haa_sym.compiled.cache: the bounded in-process memo (built once per key, first in first out
beyond its size) and the exact keys of numpy arrays."""
import numpy as np

from haa_sym.compiled.cache import BoundedCache, array_key


def test_built_once_per_key():
    cache, calls = BoundedCache(4), []

    def build(v):
        def f():
            calls.append(v)
            return [v]
        return f
    first = cache.get("a", build(1))
    assert cache.get("a", build(2)) is first and calls == [1]         # the same object, not rebuilt
    assert cache.get("b", build(3)) == [3] and calls == [1, 3] and len(cache) == 2


def test_first_in_first_out_beyond_its_size():
    cache = BoundedCache(3)
    for k in "abcd":
        cache.get(k, lambda k=k: k.upper())
    assert len(cache) == 3
    rebuilt = []
    assert cache.get("a", lambda: rebuilt.append("a") or "A2") == "A2" and rebuilt == ["a"]   # "a" went first
    assert cache.get("c", lambda: "never") == "C" and len(cache) == 3          # "b" went for "a"
    assert cache.get("b", lambda: "B2") == "B2"
    cache.clear()
    assert len(cache) == 0


def test_a_failed_build_caches_nothing():
    cache = BoundedCache(2)

    def fail():
        raise RuntimeError("no")
    try:
        cache.get("x", fail)
    except RuntimeError:
        pass
    assert len(cache) == 0 and cache.get("x", lambda: 1) == 1


def test_array_key_is_exact():
    a = np.array([[1.0, 2.0], [3.0, 4.0]])
    assert array_key(a) == array_key(a.copy()) and hash(array_key(a, a[:, :1]))
    assert array_key(a) == array_key(np.asfortranarray(a))                  # the memory order does not
    assert array_key(a) != array_key(a.astype(np.float32))                 # the dtype counts
    assert array_key(a) != array_key(a.reshape(4))                          # the shape counts
    b = a.copy()
    b[0, 0] = np.nextafter(1.0, 2.0)
    assert array_key(a) != array_key(b)                                     # one ulp counts
    assert array_key(np.array([0.0])) != array_key(np.array([-0.0]))        # so does the sign of zero
    assert array_key([1.0, 2.0]) == array_key(np.array([1.0, 2.0]))        # lists as arrays


def test_threads_evicting_at_once_neither_fail_nor_overgrow():
    """Four threads missing distinct keys on a full cache: every get returns its own build and
    the cache never exceeds its size (without the lock, two threads evicted the same oldest entry:
    KeyError, or "dictionary changed size during iteration", seen in `haa-sym schedule`'s threads)."""
    import sys
    import threading
    cache = BoundedCache(size=8)
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)                 # switch threads often: make the race likely
    errors, sizes = [], []

    def work(offset):
        try:
            for i in range(4000):
                key = (offset, i)
                assert cache.get(key, lambda: key) == key
                sizes.append(len(cache))
        except Exception as exc:               # noqa: BLE001 - report any failure of a thread
            errors.append(exc)
    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    try:
        for t in threads:
            t.join()
    finally:
        sys.setswitchinterval(interval)
    assert errors == [] and max(sizes) <= 8
