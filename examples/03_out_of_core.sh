#!/usr/bin/env bash
# Tutorial 3: out-of-core under a memory budget (docs/tutorial.md).
# A bare bed of 100 000 discs stepped with one slab and its halo in RAM at a time, the rest
# in the store on disk; then the same steps in one piece, and the two final states compared
# bit for bit. Usage: examples/03_out_of_core.sh [OUT]  (default runs/ooc)
set -euo pipefail
out="${1:-runs/ooc}"
steps=96

# what would the budget give? `check` plans without running: with --memory, out-of-core
# takes the fewest sub-domains D (the largest slab) and the block K of steps per sweep whose
# slab, halo and I/O buffers fit, and prints them with the expected peak (memory_bytes)
ooc-dem check bed-100k --mode ooc --memory 230MB --steps "$steps"

# run it: D and K are chosen as above, stated on stderr and stored with the run
ooc-dem run bed-100k --mode ooc --memory 230MB --steps "$steps" --out "$out/ooc" --no-progress

# the same steps with the whole bed in RAM (about 300 MB here: over that budget)
ooc-dem run bed-100k --steps "$steps" --out "$out/monolithic" --no-progress

# the canonical state hash of each store, and the comparison: bit-identical
ooc-dem checkpoint hash "$out/ooc"
ooc-dem checkpoint hash "$out/monolithic"
ooc-dem compare "$out/ooc" "$out/monolithic"
