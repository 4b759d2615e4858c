"""The 1000-disk pour of vs_lammps.py with and without running its chunks on
blocks of the poured disks (`jaxpile.engine.blocks`), one process each:

    NOBLOCKS=1 python benchmarks/pour_blocks_ab.py OUT_OFF.json   # the full array every chunk
    python benchmarks/pour_blocks_ab.py OUT_ON.json               # as jaxpile runs it

Blocks make a CPU pour pay only for the disks poured (issue 15); on a GPU a
small pile's step costs its kernel launches whatever its size, so what a block
saves there is set against the compile each block size costs. Measured on one
H200 in one call: benchmarks/results/gpu/pour_blocks_ab.json.
"""

import os
import runpy
import sys

import jaxpile.engine.blocks as blocks

if os.environ.get("NOBLOCKS"):
    blocks.block_size = lambda needed, count: None  # every chunk on the full array
print("blocks", "off" if os.environ.get("NOBLOCKS") else "on", flush=True)
here = os.path.dirname(os.path.abspath(__file__))
sys.argv = ["vs_lammps.py", "--cases", "pour", "--pour-laws", "", "--out", sys.argv[1]]
sys.path.insert(0, here)
runpy.run_path(os.path.join(here, "vs_lammps.py"), run_name="__main__")
