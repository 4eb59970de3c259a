"""The triaxial test with a latex membrane: a specimen between two platens, wrapped in a clamped membrane.

Contract. :func:`membrane_test` builds the coupled system of :mod:`membrax.membrane.coupled` around a specimen
— the two platens (servo or strain controlled, frictionless by default), no lateral walls, and a membrane
mesh whose mid-surface sits t_m/2 outside the outer particles, its corners rounded about the corner spheres
(:func:`membrax.membrane.mesh.prism_mesh` with ``corner_radius`` = R), with its end rings clamped to the
platens — and returns a :class:`MembraneTest`. Its methods run the stages with the chunk driver and
return the state and the records (:class:`membrax.membrane.records.MembraneMeasurements`, numpy arrays
with a leading time axis):

- :meth:`MembraneTest.consolidate` (stage 1): the cell pressure acts on the membrane's outer face; both
  platens are servo-controlled to a ram force of σc × platen area (the ram balances the spheres and the
  membrane on the platen, :mod:`membrax.membrane.coupled`), until the unbalanced-force ratio falls below
  ``tolerance`` and the ram stress is within ``stress_tolerance`` of σc;
- :meth:`MembraneTest.shear` (stage 2): drained shearing, both platens closing at ε̇ H₁/2 each (H₁ the
  height after consolidation; or the top one alone at ε̇ H₁, ``symmetric=False``) from an inertial number
  I = ε̇ d √(ρ/σc) (GDR MiDi 2004), ramped up from rest until the axial strain reaches ``ramp_strain``
  (:data:`membrax.defaults.SHEAR_RAMP_STRAIN`), the cell pressure constant, to a target axial strain.
  Records every ``record_every_fine`` steps below ``fine_until_strain`` (the FCC peak is a spike within
  0.01–0.1 % strain), every ``record_every_coarse`` after. :meth:`MembraneTest.phase_plan` gives the step
  counts of every phase (:mod:`membrax.runner` runs them, with checkpoints and resume within a phase).

Time step: Δt = ``dt_safety`` × min(Δt_crit of the DEM, Δt_crit of the membrane with its contacts,
:func:`membrax.membrane.stability.membrane_critical_time_step`); both are kept in ``critical_dt``.
Those are the rest stiffness's; under the Gent law the step is checked against the stiffening toward the
lock: the coupled step sets ``ErrorCode.MEMBRANE_STIFFENED`` once the largest (I₁ − 3)/J_m passes
s_stable (:attr:`MembraneTest.stable_locking_ratio`, from
:func:`membrax.membrane.stability.membrane_tangent_limit`), and the run stops with a
:class:`membrax.errors.SimulationError` naming the stretch reached, s_stable and the fix. The membrane
may touch any sphere (the candidate search runs over all of them through a cell list,
:func:`membrax.membrane.candidates.build_candidates`). Units: the builder takes laboratory units (kPa, mm),
named in the arguments; everything inside is SI.
"""

from __future__ import annotations

import dataclasses as pydataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from membrax.defaults import GENT_LOCKING_JM, LATEX_DENSITY, MEMBRANE_MODULUS, SHEAR_RAMP_STRAIN
from membrax.driver import ChunkRunner
from membrax.errors import ErrorCode
from membrax.membrane.candidates import grown_candidate_capacities
from membrax.membrane.contact import MembraneContactParams
from membrax.membrane.coupled import (
    CoupledParams,
    CoupledState,
    MembraneParams,
    grow_candidates,
    membrane_dem,
)
from membrax.membrane.energies import locking_ratio, stable_locking_ratio
from membrax.membrane.measure import max_sphere_penetration
from membrax.membrane.mesh import MembraneMesh, cylinder_mesh, inner_volume, prism_mesh
from membrax.membrane.records import measure_coupled
from membrax.membrane.stability import membrane_critical_time_step, membrane_tangent_limit
from membrax.spheres.contact import ContactParams
from membrax.spheres.fcc import Specimen
from membrax.spheres.grading import RandomSpecimen
from membrax.spheres.integrate import (
    DampingParams,
    DEMParams,
    make_particles,
    sphere_dem,
)
from membrax.spheres.neighbors import pair_neighbor_fn
from membrax.spheres.particles import GRANITE_DENSITY
from membrax.spheres.stability import DEFAULT_SAFETY, critical_time_step
from membrax.spheres.walls import BOTTOM, TOP, ramp_acceleration, set_control, triaxial_walls
from membrax.theory import strain_rate_from_inertial_number
from membrax.triaxial.protocol import StagedTest
from membrax.validation import check_range

__all__ = ["MembraneTest", "membrane_test"]


#: Largest change of the volumetric strain over the last consolidation chunk (:meth:`is_consolidated`).
VOLUME_TOLERANCE = 1e-4


@pydataclasses.dataclass
class MembraneTest(StagedTest):
    """A specimen in a membrane, ready to run (built by :func:`membrane_test`).

    Its stages, :meth:`consolidate` (stop criteria ``stress_tolerance``, ``volume_tolerance``:
    :meth:`is_consolidated`) and :meth:`shear` (``ramp_strain``, ``symmetric``: :meth:`start_shear`), are
    :class:`membrax.triaxial.protocol.StagedTest`'s.
    """

    cell = "membrane"
    default_ramp_strain = SHEAR_RAMP_STRAIN

    specimen: Specimen
    particles: object
    mesh: MembraneMesh
    params: CoupledParams
    dt: float
    critical_dt: dict
    initial_state: CoupledState
    runner: ChunkRunner
    initial_height: float
    initial_volume: float
    platen_area: float
    density: float
    #: ``make_step(mesh, limit=tangent_limit) -> step_fn``: the coupled step around another mesh of the same
    #: topology (a traced one, e.g. another thickness's rest geometry inside a batch, :mod:`membrax.sweep`),
    #: checking the Gent stiffening against ``limit`` (a batch passes its members' smallest).
    make_step: object = None
    #: ``make_record(mesh, initial_volume) -> record_fn(state, params)``: the measurements around such a mesh.
    make_record: object = None
    #: r_max, the largest Gent tangent ratio k_t/k_0 that ``dt`` tolerates
    #: (:func:`membrax.membrane.stability.membrane_tangent_limit`; ``inf`` under the other laws, unchecked).
    tangent_limit: float = math.inf
    #: s_stable, the largest (I₁ − 3)/J_m the step tolerates under the Gent law
    #: (:func:`membrax.membrane.energies.stable_locking_ratio`; ``inf`` under the other laws).
    stable_locking_ratio: float = math.inf

    @property
    def cell_pressure(self) -> float:
        """σc, Pa."""
        return float(self.params.membrane.cell_pressure)

    def max_penetration(self, state: CoupledState):
        """The deepest a sphere passes through the membrane's mid-surface at ``state``, m (scalar).

        :func:`membrax.membrane.measure.max_sphere_penetration` over the membrane's candidate table (−inf
        when no sphere is a candidate).
        """
        return max_sphere_penetration(
            state.membrane.position,
            self.mesh.triangles,
            state.dem.position,
            self.particles.radius,
            state.membrane.candidates.idx,
        )

    def set_platens(self, state: CoupledState, servo, velocity, target, acceleration=np.inf) -> CoupledState:
        """A copy of ``state`` with the platens' mode, velocity (dh/dt, m/s), target stress (Pa) and ramp set.

        ``acceleration`` (m/s², inf: none) ramps constant-velocity platens up from rest
        (:func:`membrax.spheres.walls.set_control`).
        """
        walls = set_control(state.dem.walls, servo, velocity, target, acceleration)
        return state.set(dem=state.dem.set(walls=walls))

    def start_consolidation(self, state: CoupledState) -> CoupledState:
        """Switch ``state`` to stage 1: both platens servo-controlled to the ram force σc × A₀, at rest."""
        return self.set_platens(state, True, 0.0, self.cell_pressure)

    def is_consolidated(
        self,
        records,
        tolerance: float,
        stress_tolerance: float = 0.01,
        volume_tolerance: float = VOLUME_TOLERANCE,
    ) -> bool:
        """The consolidation stop test on a chunk's records: true when all three hold.

        - the unbalanced-force ratio of the last record is below ``tolerance``;
        - ram force / A₀ = σc within ``stress_tolerance`` (the servo holds the ram, spheres + membrane on
          the platen, at σc A₀, A₀ the platen area);
        - the membrane has settled: ε_v changed by less than ``volume_tolerance`` between the chunk's first
          and last records. The UFR alone is not enough: while the membrane is still creeping into the voids
          the spheres can be near balance (a paper-size run met UFR < 2e-2 after 2,000 of its ~13,000
          steps).
        """
        ratio = float(records.unbalanced_force_ratio[-1, 0])
        stress = float(records.ram_force[-1, 0]) / self.platen_area
        volumetric_strain = np.asarray(records.volumetric_strain)[:, 0]
        creep = abs(float(volumetric_strain[-1] - volumetric_strain[0]))
        return (
            ratio < tolerance
            and abs(stress / self.cell_pressure - 1.0) < stress_tolerance
            and creep < volume_tolerance
        )

    def shear_rate(self, inertial_number: float, cell_pressure=None) -> float:
        """Axial strain rate ε̇ = I / (d √(ρ/σc)) for an inertial number I (GDR MiDi 2004), 1/s.

        ``cell_pressure`` (Pa, default the test's) may be traced (:mod:`membrax.gradients`).
        """
        check_range("inertial_number", inertial_number, lower=0.0, lower_open=True)
        pressure = self.cell_pressure if cell_pressure is None else cell_pressure
        return strain_rate_from_inertial_number(
            inertial_number, self.specimen.particle_diameter, self.density, pressure
        )

    def start_shear(
        self,
        state: CoupledState,
        inertial_number: float = 1e-3,
        ramp_strain: float = SHEAR_RAMP_STRAIN,
        symmetric: bool = True,
        cell_pressure=None,
    ) -> CoupledState:
        """Switch ``state`` to stage 2: the platens close at ε̇ H (H the current height), ramped up from rest.

        Traceable in ``state`` and ``cell_pressure``: a rollout starts shearing inside a differentiated
        function (:func:`membrax.gradients.shearing_rollout`).

        Args:
          state: the consolidated state.
          inertial_number: I, setting ε̇ (:meth:`shear_rate`).
          ramp_strain: axial strain at which the platens reach full speed; the ramp is linear in time and
            lasts 2 ε_ramp/ε̇ (0: a step change). Its purpose and default:
            :data:`membrax.defaults.SHEAR_RAMP_STRAIN`.
          symmetric: both platens move, each at ε̇ H/2 (the specimen's mid-height stays put, so the two
            ends bulge alike); False: the bottom platen fixed and the top one at ε̇ H.
          cell_pressure: σc, Pa, setting ε̇ and the platens' (unused) servo target; default the test's.
        """
        check_range("ramp_strain", ramp_strain, lower=0.0, upper=1.0, upper_open=True)
        walls = state.dem.walls
        height = walls.position[0, TOP] + walls.position[0, BOTTOM]
        rate = self.shear_rate(inertial_number, cell_pressure)
        moving = np.zeros(walls.velocity.shape)  # the share of ε̇ H each wall closes at
        if symmetric:
            moving[0, [BOTTOM, TOP]] = 0.5
        else:
            moving[0, TOP] = 1.0
        if isinstance(height, jax.core.Tracer) or isinstance(rate, jax.Array):
            velocity = -jnp.asarray(moving, height.dtype) * (rate * height)
        else:  # on the host in float64, rounded once into the state (set_control)
            velocity = -moving * (rate * float(height))
        acceleration = ramp_acceleration(velocity, rate, ramp_strain)
        target = self.cell_pressure if cell_pressure is None else cell_pressure
        return self.set_platens(state, False, velocity, target, acceleration)

    def ramp_transit_ratio(
        self, inertial_number: float = 1e-3, ramp_strain: float = SHEAR_RAMP_STRAIN
    ) -> float:
        """The ramp's duration 2 ε_ramp/ε̇ over the compression wave's transit time H/c, dimensionless.

        c = d √(k_n/m) is the wave speed of a chain of spheres of diameter d, mass m and contact stiffness
        k_n (the long-wavelength limit of a 1D mass–spring lattice), H the as-built height.
        """
        mass = float(self.particles.mass[0])
        stiffness = float(np.ravel(np.asarray(self.params.dem.contact.normal_stiffness))[0])
        speed = self.specimen.particle_diameter * np.sqrt(stiffness / mass)
        ramp_time = 2.0 * ramp_strain / self.shear_rate(inertial_number)
        return float(ramp_time * speed / self.initial_height)


def membrane_test(
    specimen: Specimen | RandomSpecimen,
    cell_pressure: float,
    membrane_thickness: float,
    membrane_modulus: float = MEMBRANE_MODULUS,
    contact_params: ContactParams | None = None,
    membrane_contact: MembraneContactParams | None = None,
    damping: DampingParams | None = None,
    density: float = GRANITE_DENSITY,
    latex_density: float = LATEX_DENSITY,
    edges_per_diameter: float = 5.0,
    candidate_capacity: int = 3,
    dt_safety: float = DEFAULT_SAFETY,
    skin_fraction: float = 0.2,
    servo_gain: float = 0.1,
    max_wall_speed: float | None = None,
    time_step: float | None = None,
    bending_factor: float = 0.0,
    nodes_around: int | None = None,
    contact_offset_factor: float = 1.0,
    stretching_model: str = "neo_hookean",
    locking_jm: float = GENT_LOCKING_JM,
    contact_model: str = "nodes",
) -> MembraneTest:
    """Build a membrane triaxial test on a specimen (module docstring); defaults are the paper's.

    Args:
      specimen: from :func:`membrax.spheres.fcc.fcc_specimen`, or a random one
        (:meth:`membrax.spheres.compaction.Compaction.specimen`: a cylindrical mesh of its diameter, every
        sphere a candidate of the node–sphere contact).
      cell_pressure: σc, Pa, > 0 (paper: 1e4, 4e4, 1e5).
      membrane_thickness: t_m, m, > 0 (paper: 2.5e-3, 3.33e-3, 5e-3).
      membrane_modulus: E_m, Pa, > 0 (paper: 1.4e6, :data:`membrax.defaults.MEMBRANE_MODULUS`).
      contact_params: sphere contact law (default :meth:`ContactParams.paper`).
      membrane_contact: the membrane–sphere law's parameters (default :meth:`MembraneContactParams.default`).
      damping: default Cundall local 0.3 (paper), applied to spheres and membrane nodes alike, on their
        velocities relative to the platens' affine field (:data:`membrax.defaults.DAMPING_FRAME`).
      density: particle density, kg/m³.
      latex_density: membrane density, kg/m³.
      edges_per_diameter: mesh resolution, particle diameter / target edge length (5: ~34,000 triangles at
        paper size, as the paper).
      candidate_capacity: initial K of the node candidate table (grown on overflow).
      dt_safety: Δt = dt_safety × the smaller critical step.
      skin_fraction: neighbour and candidate skin as a fraction of the particle diameter.
      servo_gain: the platen servo's α.
      max_wall_speed: servo speed limit, m/s (default: 1 % of a diameter per 1000 steps).
      time_step: Δt in s, overriding the rule above.
      bending_factor: scale of the membrane's bending rigidity, >= 0: 1 the plate's E t³/12(1 − ν²), 0 (the
        default) a pure membrane, which the paper's mesh appears to have been: at paper size, 10 kPa, 5 mm,
        it ends consolidation (float64, unbalanced-force ratio 4e-5) with internal σ3 and σ1 of 10.86 and
        13.12 kPa (paper: 11.8, 14.6); plate bending spans the FCC faces' troughs stiffly and ends
        consolidation in hoop compression, internal σ3 below σc (9.7 kPa).
      nodes_around: n_θ, membrane nodes per ring (default: perimeter / edge length); a batch over thickness
        fixes it so that all its meshes share one topology (:mod:`membrax.sweep`).
      contact_offset_factor: nodes touch spheres at R + f t_m/2 (1: the membrane's inner face on the
        sphere; 0: its nodes on the sphere surface, the paper's; :class:`MembraneParams`). The mesh is
        built f t_m/2 outside the outer spheres, where its nodes would touch them.
      stretching_model: the membrane's stretching law, ``"neo_hookean"`` (the paper's), ``"gent"`` or
        ``"svk"`` (:func:`membrax.membrane.energies.stretching_energy`).
      locking_jm: the Gent law's J_m, > 0 (:data:`membrax.defaults.GENT_LOCKING_JM`).
      contact_model: ``"nodes"`` (the spheres meet the membrane's nodes) or ``"faces"`` (its faces, edges
        and nodes, :mod:`membrax.membrane.face_contact`; compiled CPU kernels forward and
        backward).
    """
    check_range("cell_pressure", cell_pressure, lower=0.0, lower_open=True, hint="Pa; 10 kPa is 1e4.")
    check_range("edges_per_diameter", edges_per_diameter, lower=0.0, lower_open=True)
    check_range("dt_safety", dt_safety, lower=0.0, upper=1.0, lower_open=True)
    membrane_params = MembraneParams.create(
        thickness=membrane_thickness,
        cell_pressure=cell_pressure,
        modulus=membrane_modulus,
        contact=membrane_contact,
        bending_factor=bending_factor,
        contact_offset_factor=contact_offset_factor,
        locking_jm=locking_jm,
    )
    contact_params = ContactParams.paper() if contact_params is None else contact_params
    damping = DampingParams.local(0.3) if damping is None else damping
    params = CoupledParams(dem=DEMParams(contact=contact_params, damping=damping), membrane=membrane_params)
    diameter = specimen.particle_diameter
    # The thickness the node–sphere contact sees: nodes touch spheres at R + contact_thickness/2.
    contact_thickness = contact_offset_factor * membrane_thickness
    position = jnp.asarray(specimen.position)
    particles = make_particles(jnp.asarray(specimen.radius), density)
    walls = triaxial_walls(
        np.zeros((0, 2)), np.zeros(0), specimen.height, num_members=1, servo_gain=servo_gain
    )
    largest = specimen.largest_diameter
    lower = np.min(np.asarray(position), axis=0) - 2.0 * largest
    upper = np.max(np.asarray(position), axis=0) + 2.0 * largest
    frame = pair_neighbor_fn(
        lower, upper, cutoff=largest, skin=skin_fraction * diameter, margin=0.5 * largest
    )
    neighbors = frame.allocate(position)
    circular = specimen.cross_section == "circle"
    if circular:  # a random specimen: a cylinder of its diameter
        mesh = cylinder_mesh(
            0.5 * (specimen.diameter + contact_thickness),
            specimen.height,
            diameter / edges_per_diameter,
            dtype=position.dtype,
            num_around=nodes_around,
        )
    else:
        mesh = prism_mesh(
            np.asarray(specimen.outline_vertices),
            0.5 * contact_thickness,
            specimen.height,
            diameter / edges_per_diameter,
            dtype=position.dtype,
            # Rounded about the outer spheres: a mitred band leaves the corners unsupported, and cell
            # pressure closing those gaps shortens the perimeter by ~1 %, i.e. hoop compression.
            corner_radius=0.5 * diameter,
            num_around=nodes_around,
        )
    # FCC: the critical step of the touching lattice (a seeded imperfection, packing.with_imperfection,
    # opens its contacts, which close under load, and leaves the masses within 3 f of the nominal ones). A
    # compacted random specimen's contacts are closed as built.
    nominal = particles.radius if circular else jnp.full_like(particles.radius, 0.5 * diameter)
    lattice = make_particles(nominal, density)
    dem_init, _ = sphere_dem(lattice, frame, 1.0)
    critical = {"dem": critical_time_step(dem_init(position, walls, neighbors), lattice, params.dem)}
    membrane_steps = membrane_critical_time_step(
        mesh, membrane_params, latex_density, stretching_model=stretching_model
    )
    critical.update({f"membrane_{key}": value for key, value in membrane_steps.items()})
    dt = dt_safety * min(critical["dem"], critical["membrane_combined"]) if time_step is None else time_step
    if max_wall_speed is None:
        max_wall_speed = 0.01 * diameter / (1000 * dt)
    walls = walls.set(max_speed=jnp.full(walls.max_speed.shape, max_wall_speed, walls.max_speed.dtype))
    platen_area = float(specimen.cross_section_area)

    gent = stretching_model == "gent"
    tangent_limit = membrane_tangent_limit(dt, membrane_steps) if gent else math.inf
    stable_ratio = stable_locking_ratio(tangent_limit, locking_jm) if gent else math.inf
    law = {
        "latex_density": latex_density,
        "stretching_model": stretching_model,
        "contact_model": contact_model,
        "tangent_limit": tangent_limit,
    }

    def make_step(member_mesh, limit=tangent_limit):
        return membrane_dem(
            particles, frame, member_mesh, dt, platen_area, **{**law, "tangent_limit": limit}
        )[1]

    def make_record(member_mesh, member_volume):
        def record(s, p):
            return measure_coupled(s, particles, member_mesh, p, dt, height, member_volume, platen_area)

        return record

    init_fn, step_fn = membrane_dem(particles, frame, mesh, dt, platen_area, **law)
    state = init_fn(
        dem_init(position, walls, neighbors), params, candidate_capacity, skin=skin_fraction * diameter
    )
    height = float(specimen.height)
    volume = float(inner_volume(state.membrane.position, mesh, contact_thickness))

    record = make_record(mesh, volume)

    def grow(s, overflowed_state):
        capacities = grown_candidate_capacities(s.membrane.candidates, overflowed_state.membrane.candidates)
        return grow_candidates(s, particles, capacities, contact_thickness, mesh)

    def explain(error, end, start, run_params):
        """The stretch the membrane reached, for a Gent run stopped near its lock or on non-finite values."""
        watched = ErrorCode.MEMBRANE_STIFFENED | ErrorCode.MEMBRANE_LOCKED | ErrorCode.NOT_FINITE
        if not gent or not error & watched:
            return ""
        jm = float(run_params.membrane.locking_jm)  # the run's J_m (traced: not necessarily the built one)
        reached = [float(locking_ratio(s.membrane.position, mesh, jm)) for s in (end, start)]
        reached = reached[0] if math.isfinite(reached[0]) else reached[1]
        return (
            f" (the membrane's largest (I1 - 3)/J_m reached {reached:.3f} at J_m = {jm:.3g}; at dt = "
            f"{dt:.3g} s its step is stable to s_stable = {stable_locking_ratio(tangent_limit, jm):.3f}, "
            "and Gent's law is continued past 0.9)"
        )

    runner = ChunkRunner(
        step_fn,
        frame,
        record,
        particles.num_particles,
        grow_membrane=grow,
        dem_of=lambda s: s.dem,
        with_dem=lambda s, dem: s.set(dem=dem),
        explain=explain,
    )
    return MembraneTest(
        specimen=specimen,
        particles=particles,
        mesh=mesh,
        params=params,
        dt=float(dt),
        critical_dt=critical,
        initial_state=state,
        runner=runner,
        initial_height=height,
        initial_volume=volume,
        density=float(density),
        platen_area=platen_area,
        make_step=make_step,
        make_record=make_record,
        tangent_limit=float(tangent_limit),
        stable_locking_ratio=float(stable_ratio),
    )
