"""The ranges the closed forms check their concrete arguments against.

Contract. Keyword arguments of :func:`membrax.validation.check_range`, shared by the modules of
:mod:`membrax.theory`; private to it.
"""

#: Strictly positive: moduli, thicknesses, diameters, stresses that divide.
POSITIVE = {"lower": 0.0, "lower_open": True}
#: A strain as a fraction, compression positive, below 1.
STRAIN = {"upper": 1.0, "upper_open": True}
#: The hint of a strain out of range.
STRAIN_HINT = "Strains are fractions (0.05 for 5 %), compression positive, and must stay below 1."
#: An angle in degrees in [0, 90).
ANGLE_DEG = {"lower": 0.0, "upper": 90.0, "upper_open": True}
