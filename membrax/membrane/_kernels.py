"""The membrane's compiled CPU kernels on the JAX side: flat inputs, calls, residuals, backward rules.

Contract. Private to :mod:`membrax.membrane`. For each law with a kernel in :mod:`membrax.native`
(the membrane forces, ``membrane_forces.cc``; the node–sphere contact, ``node_sphere.cc``; the face contact,
``face_contact.cc``; the node update,
``membrane_nodes.cc``; the three chained as one node step), the functions that turn the law's arguments
into the kernel's flat operands (``*_inputs``), call the forward kernel (``*_kernel``), choose what reverse
mode keeps (``*_residuals``) and run the backward kernels (``*_backward``). The laws themselves, their JAX
definitions (the references) and their :func:`membrax.native.with_reference` bindings stay in
:mod:`membrax.membrane.energies`, :mod:`membrax.membrane.contact` and
:mod:`membrax.membrane.node_update`, which import these.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from membrax import native
from membrax.defaults import GENT_LOCKING_JM, LATEX_POISSON_RATIO, STRETCHING_MODELS

# The membrane forces (membrane_forces.cc): −∇ of the membrane's energy, on nodal_forces' arguments.


def nodal_forces_kernel_inputs(position, mesh, *scalars):
    """The kernel's differentiable inputs: the positions and the scalars (E_m, t_m, p, ν, f_b, J_m) stacked.

    ``scalars`` are nodal_forces' after the mesh, in that order; J_m may be left out (the neo-Hookean and
    SVK laws do not read it): :data:`membrax.defaults.GENT_LOCKING_JM` then.
    """
    del mesh  # its arrays are the kernel's other inputs (_mesh_inputs), no cotangent
    if len(scalars) == 5:
        scalars = (*scalars, GENT_LOCKING_JM)
    return position, native.stack_scalars(position.dtype, *scalars)


def _mesh_inputs(mesh, dtype):
    """The kernel's mesh inputs, in its order after the positions."""
    return (
        mesh.corner_index,
        mesh.reference_inverse.astype(dtype),
        mesh.reference_area.astype(dtype),
        mesh.hinge_index,
        mesh.edge_weight.astype(dtype),
        mesh.rest_dihedral.astype(dtype),
        mesh.bottom_ring,
        mesh.top_ring,
    )


def nodal_forces_kernel(*args, model):
    """The compiled kernel's forces (``membrane_forces.cc``).

    ``args`` are those of :func:`nodal_forces_kernel_inputs` (of
    :func:`membrax.membrane.energies.reference_nodal_forces` less the model, J_m last and optional).
    """
    position, scalars = nodal_forces_kernel_inputs(*args)
    mesh = args[1]
    dtype = position.dtype
    return native.call(
        "membrane_forces",
        dtype,
        jax.ShapeDtypeStruct(position.shape, dtype),
        position,
        *_mesh_inputs(mesh, dtype),
        scalars,
        model=np.int64(STRETCHING_MODELS.index(model)),
    )


def nodal_forces_backward(args, perturbed, cotangent, model):
    """The compiled reverse-mode rule (``membrane_forces_backward``).

    J ū for the positions (the forces are −∇Φ, so J is symmetric) and ū·∂F/∂(E_m, t_m, p, ν, f_b, J_m); None
    (the reference's rule) when the mesh's rest geometry is differentiated.
    """
    if any(jax.tree.leaves(perturbed[1])):
        return None
    # At f_b = 0 the hinges only serve ∂/∂f_b: skipped unless the bending factor is differentiated.
    flat = nodal_forces_backward_kernel(args, cotangent, jnp.zeros_like(args[0]), bool(perturbed[6]), model)
    return native.pack_cotangents(nodal_forces_kernel_inputs, args, flat)


def nodal_forces_backward_kernel(args, cotangent, addend, bending_derivative, model):
    """``membrane_forces_backward`` on ``args``, the arguments of ``energies.nodal_forces`` less the model.

    Returns (addend + J ū, ū·∂F/∂(E_m, t_m, p, ν, f_b, J_m)) for ū = ``cotangent``; the first in the addend's
    buffer (aliased), so a caller that passes the positions' cotangent so far has it updated in place.
    """
    position, scalars = nodal_forces_kernel_inputs(*args)
    dtype = position.dtype
    return native.call(
        "membrane_forces_backward",
        dtype,
        (jax.ShapeDtypeStruct(position.shape, dtype), jax.ShapeDtypeStruct(scalars.shape, dtype)),
        position,
        *_mesh_inputs(args[1], dtype),
        scalars,
        cotangent.astype(dtype),
        addend.astype(dtype),
        input_output_aliases={11: 0},
        model=np.int64(STRETCHING_MODELS.index(model)),
        bending_derivative=np.int64(bending_derivative),
    )


# The kernels' side of the law. Each function below takes node_sphere_forces' first seven arguments, in
# its order, so that membrax.membrane.node_update.node_step can chain these kernels with the others of a step.


def node_sphere_kernel_inputs(nodes, spheres, candidates, spring, dt, params, membrane_thickness):
    """The kernels' differentiable inputs, flat in their order (less the candidates), the scalars stacked.

    Returns:
      (x_node, v_node, x_sphere, v_sphere, ω_sphere, R, springs, (Δt, k_n, k_t, μ, t_m)), all of the node
      positions' dtype: what :func:`membrax.native.pack_cotangents` carries the kernels' cotangents back
      through to the arguments.
    """
    del candidates  # integer ids: passed to the kernels as they are, no cotangent
    dtype = nodes.position.dtype
    node_rows = (nodes.position, nodes.velocity)
    sphere_rows = (spheres.position, spheres.velocity, spheres.angular_velocity, spheres.radius)
    law = (params.normal_stiffness, params.tangential_stiffness, params.friction_coefficient)
    return (
        *native.in_dtype(dtype, *node_rows, *sphere_rows, spring),
        native.stack_scalars(dtype, dt, *law, membrane_thickness),
    )


def kernel_operands(args):
    """The flat inputs, and the operands both kernels begin with (the int32 candidates before the springs)."""
    flat = node_sphere_kernel_inputs(*args)
    return flat, (*flat[:6], args[2].astype(jnp.int32), *flat[6:])  # between the sphere radii and the springs


def node_sphere_kernel(*args):
    """(node force, sphere force, sphere torque, new springs) from the compiled kernel (node_sphere.cc).

    The springs are updated in place (operand 7 to result 3): in a loop whose carry holds them, XLA then
    needs no copy of the new ones into the carry.
    """
    flat, operands = kernel_operands(args)
    node_position, sphere_position, spring = flat[0], flat[2], flat[6]
    dtype = node_position.dtype
    rows = jax.ShapeDtypeStruct(node_position.shape, dtype)
    sphere_rows = jax.ShapeDtypeStruct(sphere_position.shape, dtype)
    return native.call(
        "node_sphere_forces",
        dtype,
        (rows, sphere_rows, sphere_rows, jax.ShapeDtypeStruct(spring.shape, dtype)),
        *operands,
        input_output_aliases={7: 3},
    )


def backward_node_sphere_forces(args, perturbed, cotangents):
    """The compiled reverse-mode rule (``node_sphere_backward``: the law of each touching slot backwards)."""
    del perturbed  # it covers every differentiable argument
    # The node addends are zero (this law's shares alone), two buffers: each is written in place.
    position = args[0].position
    position_addend, velocity_addend = jnp.zeros_like(position), jnp.zeros_like(position)
    flat_cotangents = node_sphere_backward_kernel(args, cotangents, position_addend, velocity_addend)
    return native.pack_cotangents(node_sphere_kernel_inputs, args, flat_cotangents)


def node_sphere_backward_kernel(args, cotangents, position_addend, velocity_addend):
    """``node_sphere_backward`` on :func:`node_sphere_forces`' first seven arguments: its flat cotangents.

    Returns the cotangents of :func:`node_sphere_kernel_inputs`' arrays, from those of the four outputs of
    :func:`node_sphere_kernel` (``cotangents``). The node position's and velocity's are the addends plus
    this law's shares, in the addends' buffers, and the springs' is written over the springs' cotangent
    (``cotangents[3]``): in-place updates (``input_output_aliases``: arguments 13, 14 and 12 to results
    0, 1 and 6).
    """
    flat, operands = kernel_operands(args)
    dtype = flat[0].dtype
    return native.call(
        "node_sphere_backward",
        dtype,
        tuple(jax.ShapeDtypeStruct(array.shape, dtype) for array in flat),
        *operands,
        *(jnp.asarray(c, dtype) for c in cotangents),
        position_addend.astype(dtype),
        velocity_addend.astype(dtype),
        input_output_aliases={12: 6, 13: 0, 14: 1},
    )


# The face contact law (face_contact.cc): face_contact.face_contact_forces' arguments, the springs a tuple and
# the mesh's neighbours given.


def face_contact_kernel_inputs(
    nodes, spheres, mesh, slots, springs, dt, params, membrane_thickness, neighbours
):
    """The kernel's floating inputs, flat in its order, all of the node positions' dtype.

    x, v (nodes), x, v, ω, R (spheres), the three springs, and (Δt, k_n, k_t, μ, t_m) stacked.
    """
    del mesh, slots, neighbours  # integer tables: passed to the kernel as they are
    dtype = nodes.position.dtype
    rows = (nodes.position, nodes.velocity, spheres.position, spheres.velocity, spheres.angular_velocity)
    law = (params.normal_stiffness, params.tangential_stiffness, params.friction_coefficient)
    return (
        *native.in_dtype(dtype, *rows, spheres.radius, *springs),
        native.stack_scalars(dtype, dt, *law, membrane_thickness),
    )


def _face_contact_tables(args):
    """The kernels' integer operands after the sphere radii: the slots, the mesh's features and incidences."""
    mesh, slots, neighbours = args[2], args[3], args[8]
    num_nodes = args[0].position.shape[0]
    tables = (
        slots.face,
        slots.edge,
        slots.node,
        mesh.triangles,
        jnp.concatenate([mesh.edges, mesh.edge_opposite], axis=1),  # u, v, o₁, o₂
        jnp.where(neighbours.mask, neighbours.ids, num_nodes),
        mesh.corner_incidence,
        mesh.hinge_incidence,
    )
    return tuple(jnp.asarray(table).astype(jnp.int32) for table in tables)


def face_contact_kernel(*args):
    """(node force, sphere force, sphere torque, face, edge and node springs) from ``face_contact.cc``.

    The springs are updated in place (operands 14–16 to results 3–5).
    """
    flat = face_contact_kernel_inputs(*args)
    dtype = flat[0].dtype
    rows = jax.ShapeDtypeStruct(flat[0].shape, dtype)
    sphere_rows = jax.ShapeDtypeStruct(flat[2].shape, dtype)
    springs = tuple(jax.ShapeDtypeStruct(spring.shape, dtype) for spring in flat[6:9])
    return native.call(
        "face_contact_forces",
        dtype,
        (rows, sphere_rows, sphere_rows, *springs),
        *flat[:6],
        *_face_contact_tables(args),
        *flat[6:],
        input_output_aliases={14: 3, 15: 4, 16: 5},
    )


def face_contact_backward(args, perturbed, cotangents):
    """The compiled reverse-mode rule (``face_contact_backward``: each touching slot's law on dual numbers).

    The cotangents of :func:`face_contact_kernel_inputs`' arrays from those of the kernel's six outputs,
    carried back to the arguments (the mesh's and the slots' arrays get none: the law reads only their
    integer tables).
    """
    del perturbed  # it covers every differentiable argument
    flat = face_contact_kernel_inputs(*args)
    dtype = flat[0].dtype
    flat_cotangents = native.call(
        "face_contact_backward",
        dtype,
        tuple(jax.ShapeDtypeStruct(array.shape, dtype) for array in flat),
        *flat[:6],
        *_face_contact_tables(args),
        *flat[6:],
        *(jnp.asarray(c, dtype) for c in cotangents),
    )
    return native.pack_cotangents(face_contact_kernel_inputs, args, flat_cotangents)


def node_update_inputs(nodes, dt, damping):
    """The node update kernels' inputs after the two forces: x, c, v, v_ref, m and Δt, α, γ stacked."""
    dtype = nodes.position.dtype
    # One specimen's damping: the first entry of a per-member array.
    damping_law = (jnp.ravel(damping.local_coefficient)[0], jnp.ravel(damping.viscous_rate)[0])
    reference = nodes.reference_velocity
    reference = jnp.zeros_like(nodes.velocity) if reference is None else reference  # 0: the absolute law
    return (
        *native.in_dtype(
            dtype, nodes.position, nodes.position_compensation, nodes.velocity, reference, nodes.mass
        ),
        native.stack_scalars(dtype, dt, *damping_law),
    )


def advance_nodes_inputs(membrane_force, contact_force, nodes, dt, damping):
    """The kernels' differentiable inputs, flat (not ``nodes.free``): F_m, F_c, x, c, v, v_ref, m, Δt/α/γ."""
    forces = native.in_dtype(nodes.position.dtype, membrane_force, contact_force)
    return (*forces, *node_update_inputs(nodes, dt, damping))


def advance_nodes_kernel(*args):
    *vectors, mass, scalars = advance_nodes_inputs(*args)
    dtype = mass.dtype
    rows = jax.ShapeDtypeStruct(vectors[0].shape, dtype)
    free = args[2].free
    return native.call(
        "membrane_nodes", dtype, (rows, rows, rows, rows), *vectors, mass, free.astype(dtype), scalars
    )


def advance_nodes_residuals(args, outputs, perturbed):
    """What ``membrane_nodes_backward`` reads, for reverse mode to keep (``native.with_reference``).

    The total force F (the first output, in place of the two forces it sums), the velocities, masses, mask
    and scalars; not the positions and compensations, which the backward kernel does not read.
    """
    del perturbed  # the backward kernel covers every argument
    membrane_force, contact_force, nodes, *rest = args
    force = outputs[0]
    same = membrane_force.shape == force.shape and membrane_force.dtype == force.dtype
    absent = native.Absent.like
    return (
        force if same else membrane_force,
        absent(contact_force) if same else contact_force,
        nodes.set(position=absent(nodes.position), position_compensation=absent(nodes.position_compensation)),
        *rest,
    )


def advance_nodes_backward(args, perturbed, cotangents):
    """The compiled reverse-mode rule (``membrane_nodes_backward``), from the residuals above.

    From the arguments themselves too: the two forces are summed here, as the forward kernel sums them.
    """
    del perturbed  # it covers every differentiable argument
    total_kept = isinstance(args[1], native.Absent)  # the first slot then holds F itself
    # Zeros stand in for what was not kept: only their shapes and dtypes reach the cotangents' packing.
    args = native.zeros_for_absent(args)
    force, position, velocity, reference_bar, mass_bar, scalars_bar = advance_nodes_backward_kernel(
        args, cotangents, total_kept
    )
    # x' = x + c + Δt v': the position and the compensation share a cotangent, as do the two forces.
    flat = (force, force, position, position, velocity, reference_bar, mass_bar, scalars_bar)
    return native.pack_cotangents(advance_nodes_inputs, args, flat)


def advance_nodes_backward_kernel(args, cotangents, total_kept):
    """``membrane_nodes_backward`` on :func:`advance_nodes`' arguments: (F̄, x̄, v̄, v̄_ref, m̄, (Δt, α, γ)̄).

    ``total_kept``: the first argument is F itself (else the two forces, summed here as the forward kernel
    sums them). The kernel never reads the compensation's cotangent (x' and c' share the position's), so
    its buffer takes the positions' cotangent (argument 9 to result 1), a copy into a loop's carry saved.
    """
    *vectors, mass, scalars = advance_nodes_inputs(*args)
    dtype = mass.dtype
    rows = jax.ShapeDtypeStruct(vectors[0].shape, dtype)
    return native.call(
        "membrane_nodes_backward",
        dtype,
        (rows, rows, rows, rows, jax.ShapeDtypeStruct(mass.shape, dtype), jax.ShapeDtypeStruct((3,), dtype)),
        vectors[0] if total_kept else vectors[0] + vectors[1],
        vectors[4],
        vectors[5],
        mass,
        args[2].free.astype(dtype),
        scalars,
        *(jnp.asarray(c, dtype) for c in cotangents),
        input_output_aliases={9: 1},
    )


def node_step_parts(nodes, spheres, candidates, spring, dt, params, damping, mesh):
    """node_step's arguments split into the three laws' own: (contact, membrane, update).

    ``contact`` is node_sphere_forces' first seven arguments, ``membrane`` nodal_forces' (less the model),
    ``update`` advance_nodes' after its two forces.
    """
    contact = (nodes.for_contact(), spheres, candidates, spring, dt, params.contact, params.contact_thickness)
    membrane = (
        nodes.position,
        mesh,
        params.modulus,
        params.thickness,
        params.cell_pressure,
        LATEX_POISSON_RATIO,
        params.bending_factor,
        params.locking_jm,
    )
    return contact, membrane, (nodes, dt, damping)


def node_step_kernel(*args, model):
    contact, membrane, update = node_step_parts(*args)
    contact_outputs = node_sphere_kernel(*contact)
    internal = nodal_forces_kernel(*membrane, model=model)
    return (*contact_outputs, *advance_nodes_kernel(internal, contact_outputs[0], *update))


def node_step_kernel_inputs(*args):
    """The three kernels' flat inputs from node_step's arguments, each array once.

    The node–sphere law's (the node positions and velocities among them), the membrane forces' scalars,
    and the node update's compensations, masses and scalars: what the chained backward kernels return
    cotangents of.
    """
    contact, membrane, update = node_step_parts(*args)
    _, membrane_scalars = nodal_forces_kernel_inputs(*membrane)
    _, compensation, _, reference, mass, update_scalars = node_update_inputs(*update)
    return (
        *node_sphere_kernel_inputs(*contact),
        membrane_scalars,
        compensation,
        reference,
        mass,
        update_scalars,
    )


def node_step_residuals(args, outputs, perturbed):
    """What reverse mode keeps: the arguments but the compensation, which no kernel reads, and F."""
    mesh_perturbed = perturbed[-1]  # node_step's last argument
    if any(jax.tree.leaves(mesh_perturbed)):  # the reference's rule, from all the arguments
        return args, None
    nodes, *rest = args
    compensation = native.Absent.like(nodes.position_compensation)
    return (nodes.set(position_compensation=compensation), *rest), outputs[4]


def node_step_backward(residuals, perturbed, cotangents, model, reference):
    """The three backward kernels, chained: node update, membrane forces, node–sphere law.

    ``reference``: node_step's JAX definition (the model bound), whose rule serves where the mesh's rest
    geometry is differentiated.
    """
    args, total_force = residuals
    if total_force is None:
        return native.reference_vjp(reference, args, cotangents)
    args = native.zeros_for_absent(args)
    contact, membrane, (nodes, dt, damping) = node_step_parts(*args)
    params_perturbed = perturbed[5]  # node_step's MembraneParams
    dtype = nodes.position.dtype
    (
        node_force_bar,
        sphere_force_bar,
        torque_bar,
        spring_bar,
        total_bar,
        velocity_bar,
        position_bar,
        compensation_bar,
    ) = (jnp.asarray(c, dtype) for c in cotangents)
    # 4. The node update: F stands in for its two forces (its backward kernel reads only their sum).
    update_args = (total_force, jnp.zeros_like(total_force), nodes, dt, damping)
    force_bar, update_position_bar, update_velocity_bar, reference_bar, mass_bar, update_scalars_bar = (
        advance_nodes_backward_kernel(
            update_args, (total_bar, velocity_bar, position_bar, compensation_bar), total_kept=True
        )
    )
    # 2. The membrane forces: J ū added in place to the update's position cotangent (ū = F̄; the update's
    # kernel copied it to update_position_bar, the compensation's).
    position_sum, membrane_scalars_bar = nodal_forces_backward_kernel(
        membrane, force_bar, position_bar, bool(params_perturbed.bending_factor), model
    )
    # 1. The node–sphere law: its node force is F's share, and the ring sums read it too (node_force_bar).
    contact_flat = node_sphere_backward_kernel(
        contact,
        (force_bar + node_force_bar, sphere_force_bar, torque_bar, spring_bar),
        position_sum,
        update_velocity_bar,
    )
    # The node positions' and velocities' cotangents are whole in the contact's; the membrane's and the
    # update's scalars, the compensations', the reference velocities' and the masses' are packed beside
    # them (Δt is shared).
    flat = (
        *contact_flat,
        membrane_scalars_bar,
        update_position_bar,
        reference_bar,
        mass_bar,
        update_scalars_bar,
    )
    return native.pack_cotangents(node_step_kernel_inputs, args, flat)
