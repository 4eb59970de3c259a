"""The triaxial test: its two stages on a rigid-wall cell and on a membrane cell, and their analysis.

:mod:`~membrax.triaxial.protocol` (the stage protocol both cells share: consolidation, then shearing),
:mod:`~membrax.triaxial.rigid` (the rigid-wall reference test), :mod:`~membrax.triaxial.membrane_cell`
(the paper's test: a specimen in a clamped membrane, ram servo, ramped symmetric shearing) and
:mod:`~membrax.triaxial.analysis` (additional membrane stresses, stress ratios, φ', strain ratio, the
summary of a run).
"""
