"""Throughput of the canonical state hash (`checkpoint hash`) on a store: one warm-up, then
one timed pass over the current epoch; prints JSON. Usage: python tools/hashbench.py STORE"""

import json, time, sys
from ooc_dem.model.checkpoint import hash_epoch, open_epoch
from ooc_dem.storage import open_store

store = open_store(sys.argv[1], repair=False)
with open_epoch(store) as r:
    hash_epoch(r)  # warm-up (JIT, page cache)
    t = time.perf_counter()
    h = hash_epoch(r)
    dt = time.perf_counter() - t
    n = sum(r.domain_len(d) for d in r.domains())
store.close()
print(json.dumps({"hash": h, "discs": n, "seconds": round(dt, 3), "discs_per_s": round(n / dt)}))
