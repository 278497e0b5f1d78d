"""Work over a CPU's threads: Warp runs a CPU launch on the calling thread without Python's lock,
so a render's tiles, or a trace's bands of rows, can run side by side in one process."""
from __future__ import annotations

import contextvars
import threading
from concurrent.futures import ThreadPoolExecutor, as_completed

# a CPU render's tiles (a trace's bands) go to Renderer.cpu_threads threads: at least this many
# rays each, and about TILES_PER_THREAD a thread, so that a thread whose rows cost more does not
# hold the frame back
MIN_THREAD_RAYS = 4096
TILES_PER_THREAD = 4


def in_threads(work, items, threads: int, on_done=None, name: str = "hovr") -> tuple[list, bool]:
    """work(item) for each item over `threads` threads, each call in a copy of this thread's
    context (the resource limits in force, limits.using, hold there too). on_done(result) is
    called here, on this thread, as items finish; False stops those not started. An item's error
    is raised here once the running ones end. Returns (results in the items' order, None where
    not started; stopped)."""
    items = list(items)
    stop = threading.Event()

    def guarded(item):
        return None if stop.is_set() else work(item)

    results, stopped = [None] * len(items), False
    with ThreadPoolExecutor(max(1, int(threads)), thread_name_prefix=name) as pool:
        futures = {pool.submit(contextvars.copy_context().run, guarded, item): k for k, item in enumerate(items)}
        try:
            for f in as_completed(futures):
                results[futures[f]] = f.result()
                if on_done is not None and not stopped and results[futures[f]] is not None \
                        and on_done(results[futures[f]]) is False:
                    stopped = True
                    stop.set()
        finally:
            stop.set()  # an error in one item: those not started are not
    return results, stopped
