"""The membrane half of the simulator: a triangulated latex membrane and its coupling to the spheres.

Modules along the data flow (README, Architecture): :mod:`~membrax.membrane.mesh` (meshes, their rest
geometry and kinematics: strains, hinge angles, enclosed volume), :mod:`~membrax.membrane.energies` (the
laws: neo-Hookean or SVK stretching, Discrete Shells bending, cell pressure, nodal forces, masses),
:mod:`~membrax.membrane.contact`
(the node–sphere penalty + Coulomb law with history), :mod:`~membrax.membrane.node_update` (the nodes'
damped leapfrog, the node half of a step), :mod:`~membrax.membrane.coupled` (the coupled DEM + membrane
step, clamped rings, platen reactions), :mod:`~membrax.membrane.indentation` (a sheet pressed onto a
sphere array), :mod:`~membrax.membrane.measure` (penetration, stretches, hoop strain),
:mod:`~membrax.membrane.records` (the records of a membrane test). It builds on :mod:`membrax.spheres`,
never the other way.
"""
