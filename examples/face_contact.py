"""Node contact against face contact: how close the membrane's mid-surface comes to the spheres it wraps.

A 4 × 4 × 5 FCC specimen of 25 mm spheres in a 5 mm membrane of 1400 kPa, consolidated at 10 kPa (float64,
3,000 steps at most, to an unbalanced-force ratio of 0.01), with the spheres meeting the membrane's nodes
(``membrane_contact_model = "nodes"``) or its faces, edges and nodes (``"faces"``,
:mod:`membrax.membrane.face_contact`), on meshes of edge D/3 and D/2. For each it prints the smallest
distance from a sphere's surface to the triangulated mid-surface (:func:`membrax.membrane.measure.
max_sphere_penetration`, negated: t_m/2 = 2.5 mm where the membrane's inner face rests on the sphere), the
internal σ3 of the reference study's §4.3 at the end of consolidation, and the wall time.

Node contact holds the nodes t_m/2 off the spheres; between them the triangles sag toward the sphere, the
more the coarser the mesh. Face contact holds the whole mid-surface t_m/2 off.

Run: ``python examples/face_contact.py`` (a few minutes on 2 CPU cores).
"""

import time

import jax

jax.config.update("jax_enable_x64", True)

from membrax.spheres import fcc  # noqa: E402
from membrax.triaxial.membrane_cell import membrane_test  # noqa: E402

THICKNESS = 5e-3  # m

print(
    f"{'contact':>8}{'mesh edge':>11}{'nodes':>7}{'gap to spheres (mm)':>21}{'internal σ3 (kPa)':>19}{'s':>7}"
)
for model in ("nodes", "faces"):
    for edges_per_diameter in (3.0, 2.0):
        start = time.perf_counter()
        test = membrane_test(
            fcc.fcc_specimen(0.025, 4, 5),
            cell_pressure=1e4,
            membrane_thickness=THICKNESS,
            candidate_capacity=1,
            contact_model=model,
            edges_per_diameter=edges_per_diameter,
        )
        state, records = test.consolidate(max_steps=3000, chunk_steps=1000, record_every=100, tolerance=0.01)
        if int(state.error):
            raise SystemExit(f"{model}, D/{edges_per_diameter:g}: error bits {int(state.error)}")
        penetration = test.max_penetration(state)
        print(
            f"{model:>8}{f'D/{edges_per_diameter:g}':>11}{test.mesh.num_nodes:>7}"
            f"{-1e3 * float(penetration):>21.2f}{float(records.internal_radial_stress[-1, 0]) / 1e3:>19.2f}"
            f"{time.perf_counter() - start:>7.0f}"
        )
