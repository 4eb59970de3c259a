"""The sphere half of the simulator (DEM): an FCC specimen, its contacts, walls and platens, the step.

Named for what it simulates: ``membrax.dem`` is the step's factory (:func:`membrax.spheres.integrate.dem`,
jax-md's ``(init_fn, step_fn)`` style), part of ``import membrax``'s API.

Modules along the data flow (README, Architecture): :mod:`~membrax.spheres.packing` (FCC specimens),
:mod:`~membrax.spheres.neighbors` (jax-md cell-list pair lists), :mod:`~membrax.spheres.contact`
(Cundall–Strack sphere–sphere and sphere–plane laws), :mod:`~membrax.spheres.walls` (platens, servo walls,
ramps), :mod:`~membrax.spheres.integrate` (state, forces, damping, the leapfrog step),
:mod:`~membrax.spheres.measure` (Love–Weber and wall stresses, strains, unbalanced force). Nothing here knows
of the membrane (tests/test_architecture.py holds it), so the rigid-wall test (:mod:`membrax.triaxial.rigid`)
runs without it.
"""
