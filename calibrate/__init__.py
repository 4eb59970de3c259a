"""calibrate: membrane stress corrections fitted on membrax simulations and applied to laboratory records.

The data flow is one way, simulator results in and corrections out; nothing in :mod:`membrax` imports this
package but its command line (``membrax fit``, ``membrax correct``).

- :mod:`calibrate.datasets`: a sweep's records (``sweep.nc``) as a fitting table. The inputs are the
  quantities a laboratory measures (ε_a, ε_r, dε_r/dε_a, the hoop strain) and their dimensionless groups
  (t_m/D, E_m t_m/(σc D), D/D_s, Molenkamp & Luger's α/D, the hoop stress ratio). The targets are
  Δσ_a/σc and Δσ_r/σc.
- :mod:`calibrate.models`: correction models as pure JAX functions. :data:`~calibrate.models.PAPER` is
  the paper's correlations, physically scaled; :data:`~calibrate.models.RICH` is a richer comparison.
- :mod:`calibrate.fit`: optax fitting (Adam, then L-BFGS; float64 weighted least squares) with the
  Gauss–Newton covariance, leave-one-case-out cross-validation, and a scipy Nelder–Mead baseline.
- :mod:`calibrate.abstention`: when the correction abstains: per region of E_m t_m/(σc D), the factor
  toward no correction chosen on the cross-validated predictions, so it is never worse than none there.
- :mod:`calibrate.persistence`: fitted corrections as JSON with provenance;
  :mod:`calibrate.workflow`: ``membrax fit``.
- :mod:`calibrate.lab`: a laboratory record (CSV, units in the header) read into SI units. Every bad file
  is refused with its line, column and fix.
- :mod:`calibrate.correct`: a record corrected by none, the ASTM, Henkel & Gilbert and Kuerbis & Vaid
  corrections and the fitted one (with its uncertainty band); the shipped default correction
  (``data/default_corrections.json``). :mod:`calibrate.report`: ``membrax correct``'s CSV and plot;
  :mod:`calibrate.series`: a test series and its envelopes; :mod:`calibrate.web`: ``membrax serve``.
- :mod:`calibrate.designs`: the calibration and held-out sweeps on random packings (the laboratory-geometry
  set, the shipped correction's, and the small random grid) and FCC lattices; :mod:`calibrate.grid` runs
  them (``python -m calibrate.grid OUT --design lab``); :mod:`calibrate.evaluate`: simulated tests as
  laboratory records, and each correction's φ' error against the internal φ'.
"""
