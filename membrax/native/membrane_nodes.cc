// One step of the membrane's free nodes: total force, damping, velocity and compensated position update.
//
// An XLA FFI handler for the CPU, compiled on first use by membrax/native/__init__.py; the reference is
// membrax/membrane/coupled.py (_advance_nodes_reference), which also supplies the derivatives. Per node and
// component, with F = F_membrane + F_contact and u = v − v_ref the velocity relative to the reference field
// (the platens' affine field, or 0):
//   F_d = F − α |F| sign(u) − γ m u                 (membrax.spheres.integrate.apply_damping)
//   v' = v + Δt F_d / m on free nodes, 0 on clamped ones
//   x' + c' = x + c + Δt v'                           (membrax.walls.compensated_add, Fast2Sum)
// One pass instead of XLA's several over (n, 3) arrays, in two halves of the nodes on two threads.
//
// Inputs (T: float or double): membrane_force, contact_force, position, compensation, velocity, reference
// velocity v_ref (n, 3); mass (n,); free (n,) 1 or 0; scalars (3,) = Δt, α, γ.
// Outputs: force F, velocity v', position x', compensation c' (n, 3).

#include <cmath>
#include <cstdint>
#include <vector>

#include "ffi_bind.h"
#include "parallel.h"
#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

// sign(x): 1, −1 or 0 (jnp.sign).
template <typename T>
inline T sign_of(T x) {
  return x > T(0) ? T(1) : (x < T(0) ? T(-1) : T(0));
}

// One component's new velocity v' = v + Δt F_d/m, F_d = F − α |F| sign(u) − γ m u, u = v − v_ref, on a
// free node (0 on a clamped one). v_ref = 0 gives u = v exactly, the absolute law's bits.
template <typename T>
inline T damped_velocity(T f, T v, T reference, T m, bool moves, T dt, T local, T viscous) {
  const T relative = v - reference;
  const T damped = f - local * std::fabs(f) * sign_of(relative) - viscous * m * relative;
  return moves ? v + dt * damped / m : T(0);
}

template <typename T>
void advance(const T* __restrict membrane_force, const T* __restrict contact_force, const T* __restrict position,
             const T* __restrict compensation, const T* __restrict velocity, const T* __restrict reference,
             const T* __restrict mass, const T* __restrict free, int64_t begin, int64_t end, T dt, T local,
             T viscous, T* __restrict force, T* __restrict new_velocity, T* __restrict new_position,
             T* __restrict new_compensation) {
#pragma GCC ivdep
  for (int64_t node = begin; node < end; ++node) {
    for (int c = 0; c < 3; ++c) {
      const int64_t k = 3 * node + c;
      const T f = membrane_force[k] + contact_force[k];
      const T updated =
          damped_velocity(f, velocity[k], reference[k], mass[node], free[node] != T(0), dt, local, viscous);
      const T corrected = dt * updated + compensation[k];
      const T total = position[k] + corrected;
      force[k] = f;
      new_velocity[k] = updated;
      new_position[k] = total;
      new_compensation[k] = corrected - (total - position[k]);
    }
  }
}

template <ffi::DataType dtype>
ffi::Error membrane_nodes(ffi::Buffer<dtype> membrane_force, ffi::Buffer<dtype> contact_force,
                          ffi::Buffer<dtype> position, ffi::Buffer<dtype> compensation,
                          ffi::Buffer<dtype> velocity, ffi::Buffer<dtype> reference, ffi::Buffer<dtype> mass,
                          ffi::Buffer<dtype> free, ffi::Buffer<dtype> scalars, ffi::ResultBuffer<dtype> force,
                          ffi::ResultBuffer<dtype> new_velocity, ffi::ResultBuffer<dtype> new_position,
                          ffi::ResultBuffer<dtype> new_compensation, ffi::ThreadPool pool) {
  const int64_t n = mass.element_count();
  for (const auto* vector : {&membrane_force, &contact_force, &position, &compensation, &velocity, &reference}) {
    if (vector->element_count() != size_t(3 * n))
      return ffi::Error::InvalidArgument("membrane_nodes: (n, 3) arrays must match the n masses");
  }
  if (free.element_count() != size_t(n) || scalars.element_count() != 3)
    return ffi::Error::InvalidArgument("membrane_nodes: free must be (n,), scalars (3,)");
  const auto* s = scalars.typed_data();
  // Each node on its own: two halves of the nodes on two threads (parallel.h), the same bits.
  membrax::two_halves(pool, n, [&](int, int64_t begin, int64_t end) {
    advance(membrane_force.typed_data(), contact_force.typed_data(), position.typed_data(),
            compensation.typed_data(), velocity.typed_data(), reference.typed_data(), mass.typed_data(),
            free.typed_data(), begin, end, s[0], s[1], s[2], force->typed_data(), new_velocity->typed_data(),
            new_position->typed_data(), new_compensation->typed_data());
  });
  return ffi::Error::Success();
}


// The backward kernel of advance: the outputs' cotangents (F̄, v̄', x̄', c̄') to the inputs'. The new
// compensation c' = (Δt v' + c) − (x' − x) has a zero derivative (x' = x + Δt v' + c), as in JAX's. The
// reference enters F_d through u = v − v_ref only: ∂F_d/∂v_ref = γ m (sign(u) has a zero derivative).
template <typename T>
void advance_backward(const T* __restrict total_force, const T* __restrict velocity,
                      const T* __restrict reference, const T* __restrict mass, const T* __restrict free,
                      const T* __restrict force_bar, const T* __restrict velocity_bar,
                      const T* __restrict position_bar, int64_t num_nodes, T dt, T local, T viscous,
                      T* __restrict force_out, T* __restrict position_out, T* __restrict velocity_out,
                      T* __restrict reference_out, T* __restrict mass_out, T* __restrict dt_partial,
                      T* __restrict local_partial,
                      T* __restrict viscous_partial, T* __restrict mass_partial, T* scalars_out) {
  // Per-component partial sums (Δt̄, ᾱ, γ̄, m̄), added up after the loop: with a per-node output or a
  // float reduction inside, GCC 12 does not vectorise it.
#pragma GCC ivdep
  for (int64_t node = 0; node < num_nodes; ++node) {
    const T m = mass[node];
    const bool moves = free[node] != T(0);
    for (int c = 0; c < 3; ++c) {
      const int64_t k = 3 * node + c;
      const T f = total_force[k];
      const T v = velocity[k];
      const T u = v - reference[k];
      // damped_velocity's formula written out: a shared helper returning sign(v), F_d and v' together
      // changed the last bits of this loop's partials (measured; GCC's C++ default, -ffp-contract=fast,
      // fuses products and sums into FMAs as the code's shape allows), and the kernel keeps its bits.
      const T sign = sign_of(u);
      const T force_sign = sign_of(f);
      const T damped = f - local * std::fabs(f) * sign - viscous * m * u;
      const T updated = moves ? v + dt * damped / m : T(0);
      const T corrected_bar = position_bar[k];  // x' = x + (Δt v' + c)
      const T updated_bar = velocity_bar[k] + dt * corrected_bar;
      const T damped_bar = moves ? updated_bar * dt / m : T(0);
      dt_partial[k] = corrected_bar * updated + (moves ? updated_bar * damped / m : T(0));
      local_partial[k] = -damped_bar * std::fabs(f) * sign;
      viscous_partial[k] = -damped_bar * m * u;
      mass_partial[k] = (moves ? -updated_bar * dt * damped / (m * m) : T(0)) - damped_bar * viscous * u;
      force_out[k] = force_bar[k] + damped_bar * (T(1) - local * force_sign * sign);
      position_out[k] = corrected_bar;
      velocity_out[k] = (moves ? updated_bar : T(0)) - damped_bar * viscous * m;
      reference_out[k] = damped_bar * viscous * m;
    }
  }
  T sum_dt = 0, sum_local = 0, sum_viscous = 0;
  for (int64_t k = 0; k < 3 * num_nodes; ++k) {
    sum_dt += dt_partial[k];
    sum_local += local_partial[k];
    sum_viscous += viscous_partial[k];
  }
  for (int64_t node = 0; node < num_nodes; ++node)
    mass_out[node] = mass_partial[3 * node] + mass_partial[3 * node + 1] + mass_partial[3 * node + 2];
  scalars_out[0] = sum_dt;
  scalars_out[1] = sum_local;
  scalars_out[2] = sum_viscous;
}

// Inputs: the total force F = F_membrane + F_contact (membrane_nodes' first output, which reverse mode
// keeps instead of the two forces and the positions, which this kernel does not read), velocity and
// reference velocity (n, 3), mass (n,), free (n,), scalars (3,); then the cotangents of the four outputs
// (n, 3).
// Outputs: the cotangents of the (membrane and contact) force, position and compensation (all three
// equal to the summed ones), velocity, reference velocity (n, 3), mass (n,) and scalars (3,) = Δt, α, γ.
// The compensation's cotangent is never read (x' and c' share the position's), so a caller may alias its
// buffer to an output.
template <ffi::DataType dtype>
ffi::Error membrane_nodes_backward(ffi::Buffer<dtype> total_force, ffi::Buffer<dtype> velocity,
                                   ffi::Buffer<dtype> reference, ffi::Buffer<dtype> mass,
                                   ffi::Buffer<dtype> free, ffi::Buffer<dtype> scalars,
                                   ffi::Buffer<dtype> force_bar, ffi::Buffer<dtype> velocity_bar,
                                   ffi::Buffer<dtype> position_bar, ffi::Buffer<dtype> compensation_bar,
                                   ffi::ResultBuffer<dtype> force_out, ffi::ResultBuffer<dtype> position_out,
                                   ffi::ResultBuffer<dtype> velocity_out, ffi::ResultBuffer<dtype> reference_out,
                                   ffi::ResultBuffer<dtype> mass_out, ffi::ResultBuffer<dtype> scalars_out) {
  const int64_t n = mass.element_count();
  for (const auto* vector :
       {&total_force, &velocity, &reference, &force_bar, &velocity_bar, &position_bar, &compensation_bar}) {
    if (vector->element_count() != size_t(3 * n))
      return ffi::Error::InvalidArgument("membrane_nodes_backward: (n, 3) arrays must match the n masses");
  }
  if (free.element_count() != size_t(n) || scalars.element_count() != 3)
    return ffi::Error::InvalidArgument("membrane_nodes_backward: free must be (n,), scalars (3,)");
  const auto* s = scalars.typed_data();
  thread_local std::vector<ffi::NativeType<dtype>> partial;
  partial.resize(size_t(12 * n));
  auto* p = partial.data();
  advance_backward(total_force.typed_data(), velocity.typed_data(), reference.typed_data(), mass.typed_data(),
                   free.typed_data(), force_bar.typed_data(), velocity_bar.typed_data(), position_bar.typed_data(),
                   n, s[0], s[1], s[2], force_out->typed_data(), position_out->typed_data(),
                   velocity_out->typed_data(), reference_out->typed_data(), mass_out->typed_data(), p, p + 3 * n,
                   p + 6 * n, p + 9 * n, scalars_out->typed_data());
  return ffi::Error::Success();
}

}  // namespace

MEMBRAX_DEFINE_HANDLERS(MembraxMembraneNodes, membrane_nodes);
MEMBRAX_DEFINE_HANDLERS(MembraxMembraneNodesBackward, membrane_nodes_backward);
