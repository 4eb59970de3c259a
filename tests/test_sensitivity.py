"""membrax.sensitivities: derivatives of the consolidated equilibrium, implicit against finite differences.

The finite differences continue the simulator from the equilibrium (θ ± h, h = 1e-4 θ and 1e-5 t_m, relaxed
until the largest out-of-balance force is below 1e-9 σc A₀), so they follow the same friction history. The
two agree where that path is smooth: no node–sphere or sphere–sphere contact opens, closes or starts to
slide between θ − h and θ + h. On this specimen the relative step 1e-3 in t_m already shifts the node–sphere
contact offset (t_m/2) by a fraction of the penalty overlaps (~6 µm) and the differences lose their meaning
there; 1e-4 keeps every contact.
"""

import jax
import numpy as np
import pytest
from helpers import SMALL_MEMBRANE_TEST

from membrax import cli, sensitivities


@pytest.mark.slow
def test_implicit_derivatives_match_differences_of_the_simulator_and_the_servo_law():
    wrt = ("cell_pressure_kpa", "membrane_modulus_kpa", "membrane_thickness_mm", "particle_stiffness_n_m")
    with jax.enable_x64(True):
        equilibrium = sensitivities.consolidated(SMALL_MEMBRANE_TEST)
        values, implicit, unknowns = sensitivities.implicit_sensitivities(equilibrium, wrt)
        differences = sensitivities.continuation_differences(equilibrium, wrt)
    assert (
        unknowns
        == 6 * 54 + 3 * (equilibrium.test.mesh.num_nodes - 2 * len(equilibrium.test.mesh.bottom_ring)) + 2
    )
    external_axial, external_radial, internal_axial, internal_radial = (
        sensitivities.OUTPUTS.index(name)
        for name in (
            "external_axial_stress",
            "external_radial_stress",
            "internal_axial_stress",
            "internal_radial_stress",
        )
    )
    # the servo holds the ram at σc A₀ and the cell pressure is σc: dσ_ext/dσc = 1, and nothing else moves
    # the external stresses (per kPa of σc, in Pa: 1e3)
    np.testing.assert_allclose(implicit[[external_axial, external_radial], 0], 1e3, rtol=1e-6)
    np.testing.assert_allclose(implicit[external_radial, 1:], 0.0, atol=1e-12)
    # the internal stresses: implicit = continuation differences within 1e-3 relative. Where the elasticity
    # d ln y/d ln x is below 1e-2 (k_n: ~5e-4) the differences' own floor (outputs relaxed to ~1e-9 of the
    # load, over 2h = 2e-4 θ: ~5e-6 in elasticity) sets the bar instead: 1e-5 in elasticity.
    theta = np.asarray([getattr(SMALL_MEMBRANE_TEST, name) for name in wrt])
    for row in (internal_axial, internal_radial):
        implicit_elasticity = implicit[row] * theta / values[row]
        difference_elasticity = differences[row] * theta / values[row]
        for k in range(len(wrt)):
            if abs(difference_elasticity[k]) >= 1e-2:
                assert implicit[row, k] == pytest.approx(differences[row, k], rel=1e-3), (row, wrt[k])
            else:
                assert abs(implicit_elasticity[k] - difference_elasticity[k]) < 1e-5, (row, wrt[k])
    # the membrane stiffens with E_m: the internal σ1 (its axial pull) grows
    assert implicit[internal_axial, 1] > 0.0
    # the outputs are the §4.3 stresses: internal above external at 10 kPa in a 5 mm membrane (Table 3)
    assert values[internal_axial] > values[external_axial] == pytest.approx(1e4, rel=1e-3)


def test_an_unknown_parameter_or_output_is_refused_before_anything_runs(tmp_path, capsys):
    config = tmp_path / "small.toml"
    config.write_text("particles_across = 4\nlayers = 5\n")
    assert cli.main(["sensitivity", str(config), "--wrt", "membrane_modulus"]) == 2
    assert "membrane_modulus_kpa" in capsys.readouterr().err
    assert cli.main(["sensitivity", str(config), "--outputs", "sigma_1"]) == 2
    assert "internal_axial_stress" in capsys.readouterr().err
