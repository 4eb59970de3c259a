// One step of the membrane's free nodes: total force, damping, velocity and compensated position update.
//
// An XLA FFI handler for the CPU, compiled on first use by membrax/native.py; the reference is
// membrax/membrane_dem.py (_advance_nodes_reference), which also supplies the derivatives. Per node and
// component, with F = F_membrane + F_contact:
//   F_d = F − α |F| sign(v) − γ m v                 (membrax.integrate.apply_damping)
//   v' = v + Δt F_d / m on free nodes, 0 on clamped ones
//   x' + c' = x + c + Δt v'                           (membrax.walls.compensated_add, Fast2Sum)
// One pass instead of XLA's several over (n, 3) arrays.
//
// Inputs (T: float or double): membrane_force, contact_force, position, compensation, velocity (n, 3);
// mass (n,); free (n,) 1 or 0; scalars (3,) = Δt, α, γ.
// Outputs: force F, velocity v', position x', compensation c' (n, 3).

#include <cmath>
#include <cstdint>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

template <typename T>
void advance(const T* __restrict membrane_force, const T* __restrict contact_force, const T* __restrict position,
             const T* __restrict compensation, const T* __restrict velocity, const T* __restrict mass,
             const T* __restrict free, int64_t num_nodes, T dt, T local, T viscous, T* __restrict force,
             T* __restrict new_velocity, T* __restrict new_position, T* __restrict new_compensation) {
#pragma GCC ivdep
  for (int64_t node = 0; node < num_nodes; ++node) {
    const T m = mass[node];
    const bool moves = free[node] != T(0);
    for (int c = 0; c < 3; ++c) {
      const int64_t k = 3 * node + c;
      const T f = membrane_force[k] + contact_force[k];
      const T v = velocity[k];
      const T sign = v > T(0) ? T(1) : (v < T(0) ? T(-1) : T(0));
      const T damped = f - local * std::fabs(f) * sign - viscous * m * v;
      const T updated = moves ? v + dt * damped / m : T(0);
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
                          ffi::Buffer<dtype> velocity, ffi::Buffer<dtype> mass, ffi::Buffer<dtype> free,
                          ffi::Buffer<dtype> scalars, ffi::ResultBuffer<dtype> force,
                          ffi::ResultBuffer<dtype> new_velocity, ffi::ResultBuffer<dtype> new_position,
                          ffi::ResultBuffer<dtype> new_compensation) {
  const int64_t n = mass.element_count();
  for (const auto* vector : {&membrane_force, &contact_force, &position, &compensation, &velocity}) {
    if (vector->element_count() != size_t(3 * n))
      return ffi::Error::InvalidArgument("membrane_nodes: (n, 3) arrays must match the n masses");
  }
  if (free.element_count() != size_t(n) || scalars.element_count() != 3)
    return ffi::Error::InvalidArgument("membrane_nodes: free must be (n,), scalars (3,)");
  const auto* s = scalars.typed_data();
  advance(membrane_force.typed_data(), contact_force.typed_data(), position.typed_data(),
          compensation.typed_data(), velocity.typed_data(), mass.typed_data(), free.typed_data(), n, s[0], s[1],
          s[2], force->typed_data(), new_velocity->typed_data(), new_position->typed_data(),
          new_compensation->typed_data());
  return ffi::Error::Success();
}

}  // namespace

#define MEMBRAX_NODES_HANDLER(name, dtype)                     \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(name, membrane_nodes<dtype>,   \
                                ffi::Ffi::Bind()               \
                                    .Arg<ffi::Buffer<dtype>>() \
                                    .Arg<ffi::Buffer<dtype>>() \
                                    .Arg<ffi::Buffer<dtype>>() \
                                    .Arg<ffi::Buffer<dtype>>() \
                                    .Arg<ffi::Buffer<dtype>>() \
                                    .Arg<ffi::Buffer<dtype>>() \
                                    .Arg<ffi::Buffer<dtype>>() \
                                    .Arg<ffi::Buffer<dtype>>() \
                                    .Ret<ffi::Buffer<dtype>>() \
                                    .Ret<ffi::Buffer<dtype>>() \
                                    .Ret<ffi::Buffer<dtype>>() \
                                    .Ret<ffi::Buffer<dtype>>());

MEMBRAX_NODES_HANDLER(MembraxMembraneNodesF32, ffi::F32)
MEMBRAX_NODES_HANDLER(MembraxMembraneNodesF64, ffi::F64)
