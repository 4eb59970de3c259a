"""Files of membrax: VTK for ParaView, results tables (NetCDF3 and CSV) and checkpoints.

One module per kind of file, all written atomically (:mod:`membrax.io.files`): :mod:`membrax.io.vtk`
(membrane and particle snapshots, time series with ParaView collections), :mod:`membrax.io.results` (the
records of a run as an :class:`xarray.Dataset`, NetCDF3 and CSV, read back with dtypes restored) and
:mod:`membrax.io.checkpoint` (any pytree and host data, nothing pickled, restored bit-exact). Their public
functions are re-exported here, so ``from membrax import io; io.write_results(...)`` works.

Errors. A folder argument that exists but is not a directory, a bad stem, a file that is not a
checkpoint or results file, a damaged ``.npz``, or a checkpoint of another configuration raise
``ValueError`` naming the path and the fix; a missing file raises ``FileNotFoundError``.
"""

from membrax.io import results
from membrax.io.checkpoint import load_checkpoint, read_checkpoint_host, save_checkpoint
from membrax.io.results import *  # noqa: F403  (re-exported: the names of results.__all__)
from membrax.io.vtk import VTKSeries, read_pvd, write_membrane_vtk, write_particles_vtk

__all__ = [
    "write_membrane_vtk",
    "write_particles_vtk",
    *results.__all__,
    "VTKSeries",
    "read_pvd",
    "save_checkpoint",
    "load_checkpoint",
    "read_checkpoint_host",
]
