"""How fast this machine is right now: CPU seconds of a fixed pure-Python loop.

The lab's 2-core VM changes speed by a third within an hour (other tenants).  Run this
before and after a timing (``bench_fleet.py``, ``bench_science.py``, the suite) and quote
both: a timing is comparable with another only at a like speed.  Prints one line,
``<s> CPU s``; lower is faster (1.8-2.7 on a quiet machine here, 3.4-3.9 in a slow phase).
The loop runs at module level on purpose (global names, as the figures in the README were
taken); inside a function the same loop takes about half as long.
"""
import time

if __name__ == "__main__":
    t = time.process_time()
    s = 0
    for i in range(20_000_000):
        s += i
    print(f"{time.process_time() - t:.2f} CPU s")
