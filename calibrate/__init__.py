"""calibrate: gradient-based fitting of membrane stress corrections.

What it will hold (the data flow is one way: simulator results in, corrections out):

- datasets: membrax sweep results (xarray/NetCDF) turned into training pairs of strain measures
  (strain ratio dε_r/dε_a, radial strain ε_r, indentation ratio α/D) and additional membrane stresses
  (internal − external, axial and radial);
- correction models: parametric maps from those strain measures to the additional stresses, seeded by
  the closed forms of :mod:`membrax.theory` (the paper's Figs 7–9 correlations);
- fitting: optax optimisers on the models' parameters, with uncertainty from the residuals;
- application: the fitted corrections applied to a laboratory test record (CSV of axial force, cell
  pressure, axial and volumetric strain) to give corrected σ1, σ3 and φ'.

Nothing here is implemented yet; the simulator it depends on is built first.
"""
