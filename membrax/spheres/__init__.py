"""The sphere half of the simulator (DEM): an FCC specimen, its contacts, walls and platens, the step.

One name: the folder's step is ``membrax.sphere_dem`` (:func:`membrax.spheres.integrate.sphere_dem`, jax-md's
``(init_fn, step_fn)`` style), as the membrane's is :func:`membrax.membrane.coupled.membrane_dem`.

Modules along the data flow (README, Architecture): :mod:`~membrax.spheres.fcc` (FCC specimens),
:mod:`~membrax.spheres.neighbors` (jax-md cell-list pair lists), :mod:`~membrax.spheres.contact`
(Cundall–Strack sphere–sphere and sphere–plane laws), :mod:`~membrax.spheres.walls` (platens, servo walls,
ramps), :mod:`~membrax.spheres.integrate` (state, forces, damping, the leapfrog step),
:mod:`~membrax.spheres.measure` (Love–Weber and wall stresses, strains, unbalanced force). Nothing here knows
of the membrane (tests/test_architecture.py holds it), so the rigid-wall test (:mod:`membrax.triaxial.rigid`)
runs without it.
"""
