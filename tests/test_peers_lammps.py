"""tools/peers/lammps.py's launcher: LAMMPS must run on the ranks asked for. A launcher of
another MPI than the binary's starts R independent one-rank copies (each doing the whole
run), which once made a 2021 Debian ``lmp`` under the ``mpich`` wheel's mpirun look 2x
slower and 2x larger than it is; the tool now picks the launcher beside the binary and
refuses a run whose log says another rank count. Runs the real ``lmp`` of the test extra."""

import importlib.util
import os
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("peers_lammps_2d", ROOT / "tools" / "peers" / "lammps.py")
peers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(peers)

# a tiny Lennard-Jones melt: core LAMMPS, prints "Loop time of ... on P procs ..."
MELT = """units lj
atom_style atomic
lattice fcc 0.8442
region box block 0 4 0 4 0 4
create_box 1 box
create_atoms 1 box
mass 1 1.0
velocity all create 3.0 87287 loop geom
pair_style lj/cut 2.5
pair_coeff 1 1 1.0 1.0 2.5
fix 1 all nve
run 20
"""


def test_two_ranks_run_on_two_procs(lmp, tmp_path):
    v = peers.run_lammps(lmp, peers.pick_mpirun(lmp), 2, tmp_path, MELT, "np2", 0)
    assert v["ranks"] == 2 and v["ranks_seen"] == 2 and v["atoms"] == 256
    # LAMMPS's own profile of the run, per section (what limits it)
    shares = v["timing_breakdown"]
    assert {"pair", "neigh", "comm", "modify", "other"} <= shares.keys()
    assert abs(sum(x["percent"] for x in shares.values()) - 100.0) < 0.5


def test_launcher_of_another_mpi_is_refused(lmp, tmp_path):
    # two independent copies of the binary: what a foreign MPI's mpirun starts
    fake = tmp_path / "copies"
    fake.write_text('#!/bin/sh\nif [ "$1" = --version ]; then echo copies; exit 0; fi\nshift 4\n"$@" & "$@"\nwait\n')
    fake.chmod(0o755)
    with pytest.raises(SystemExit, match=r"LAMMPS ran on 1 procs where 2 were asked"):
        peers.run_lammps(lmp, str(fake), 2, tmp_path, MELT, "np2", 0)


def test_launcher_beside_the_binary_comes_first(lmp, tmp_path):
    mpirun = shutil.which("mpirun")
    assert mpirun, "the test extra's mpich provides mpirun"
    (tmp_path / "lmp").symlink_to(lmp)
    (tmp_path / "mpirun").symlink_to(mpirun)
    assert peers.pick_mpirun(str(tmp_path / "lmp")) == str(tmp_path / "mpirun")
    os.unlink(tmp_path / "mpirun")
    assert peers.pick_mpirun(str(tmp_path / "lmp")) == mpirun
    assert peers.pick_mpirun(str(tmp_path / "lmp"), mpirun) == mpirun
    with pytest.raises(SystemExit, match="--mpirun no-such-launcher: not found"):
        peers.pick_mpirun(lmp, "no-such-launcher")
