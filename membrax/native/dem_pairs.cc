// The DEM's sphere–sphere contacts over a neighbour list, summed per sphere, in one pass.
//
// An XLA FFI handler for the CPU, compiled on first use by membrax/native.py. For each slot (i, j) =
// idx[:, k] (padded with N) it gathers the two spheres (b = (x_j − x_i) + (c_j − c_i), positions with
// their compensation), applies the Cundall–Strack law (contact_law.h, sphere_pair; the reference is
// membrax.contact.pair_contact), zeroes the padded slots and sums per sphere: j receives (F, T_j), i
// receives (−F, T_i). membrax/integrate.py (_pair_totals_reference) is the JAX definition and supplies
// the derivatives.
//
// Inputs (T: float or double): position, compensation, velocity, angular_velocity (N, 3); radius (N,);
// idx (2, C) i32 padded with N; spring (C, 3); normal_stiffness, tangential_stiffness,
// friction_coefficient (C,); dt (1,). Outputs: totals (N, 6) force and torque per sphere; spring' and the
// force on j (C, 3), zero on padded slots.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "contact_law.h"
#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

// Pass 1, vectorised: gather, law and per-slot outputs (padded slots zeroed).
template <typename T>
void dem_pair_law(const T* __restrict position, const T* __restrict compensation, const T* __restrict velocity,
                  const T* __restrict angular, const T* __restrict radius, const int32_t* __restrict idx,
                  const T* __restrict spring, const T* __restrict kn, const T* __restrict kt,
                  const T* __restrict mu, T dt, int64_t num_spheres, int64_t num_slots, T* __restrict pair_force,
                  T* __restrict new_spring, T* __restrict torque_i, T* __restrict torque_j) {
  using Vec3 = membrax::Vec3<T>;
#pragma GCC ivdep
  for (int64_t k = 0; k < num_slots; ++k) {
    const int32_t i = idx[k], j = idx[num_slots + k];
    const bool valid = i < num_spheres;
    const int64_t gi = valid ? i : 0, gj = valid ? j : 0;
    const Vec3 branch = (Vec3{position[3 * gj], position[3 * gj + 1], position[3 * gj + 2]} -
                         Vec3{position[3 * gi], position[3 * gi + 1], position[3 * gi + 2]}) +
                        (Vec3{compensation[3 * gj], compensation[3 * gj + 1], compensation[3 * gj + 2]} -
                         Vec3{compensation[3 * gi], compensation[3 * gi + 1], compensation[3 * gi + 2]});
    const auto result = membrax::sphere_pair(
        branch, Vec3{velocity[3 * gi], velocity[3 * gi + 1], velocity[3 * gi + 2]},
        Vec3{velocity[3 * gj], velocity[3 * gj + 1], velocity[3 * gj + 2]},
        Vec3{angular[3 * gi], angular[3 * gi + 1], angular[3 * gi + 2]},
        Vec3{angular[3 * gj], angular[3 * gj + 1], angular[3 * gj + 2]}, radius[gi], radius[gj],
        Vec3{spring[3 * k], spring[3 * k + 1], spring[3 * k + 2]}, kn[k], kt[k], mu[k], dt);
    const T keep = valid ? T(1) : T(0);
    const T f[3] = {keep * result.force_on_j.x, keep * result.force_on_j.y, keep * result.force_on_j.z};
    const T s[3] = {keep * result.spring.x, keep * result.spring.y, keep * result.spring.z};
    const T ti[3] = {keep * result.torque_on_i.x, keep * result.torque_on_i.y, keep * result.torque_on_i.z};
    const T tj[3] = {keep * result.torque_on_j.x, keep * result.torque_on_j.y, keep * result.torque_on_j.z};
    for (int c = 0; c < 3; ++c) {
      pair_force[3 * k + c] = f[c];
      new_spring[3 * k + c] = s[c];
      torque_i[3 * k + c] = ti[c];
      torque_j[3 * k + c] = tj[c];
    }
  }
}

template <ffi::DataType dtype>
ffi::Error dem_pairs(ffi::Buffer<dtype> position, ffi::Buffer<dtype> compensation, ffi::Buffer<dtype> velocity,
                     ffi::Buffer<dtype> angular_velocity, ffi::Buffer<dtype> radius, ffi::Buffer<ffi::S32> idx,
                     ffi::Buffer<dtype> spring, ffi::Buffer<dtype> normal_stiffness,
                     ffi::Buffer<dtype> tangential_stiffness, ffi::Buffer<dtype> friction_coefficient,
                     ffi::Buffer<dtype> time_step, ffi::ResultBuffer<dtype> totals,
                     ffi::ResultBuffer<dtype> new_spring, ffi::ResultBuffer<dtype> pair_force) {
  using T = ffi::NativeType<dtype>;
  const int64_t n = radius.element_count();
  const int64_t slots = spring.element_count() / 3;
  for (const auto* rows : {&position, &compensation, &velocity, &angular_velocity}) {
    if (rows->element_count() != size_t(3 * n))
      return ffi::Error::InvalidArgument("dem_pairs: sphere arrays must be (N, 3) with N the radii's length");
  }
  for (const auto* scalar : {&normal_stiffness, &tangential_stiffness, &friction_coefficient}) {
    if (scalar->element_count() != size_t(slots))
      return ffi::Error::InvalidArgument("dem_pairs: per-slot parameters must be (C,)");
  }
  if (idx.element_count() != size_t(2 * slots)) return ffi::Error::InvalidArgument("dem_pairs: idx must be (2, C)");
  thread_local std::vector<T> scratch;
  scratch.resize(size_t(6 * slots));
  T* torque_i = scratch.data();
  T* torque_j = torque_i + 3 * slots;
  T* force = pair_force->typed_data();
  const int32_t* id = idx.typed_data();
  dem_pair_law<T>(position.typed_data(), compensation.typed_data(), velocity.typed_data(),
                  angular_velocity.typed_data(), radius.typed_data(), id, spring.typed_data(),
                  normal_stiffness.typed_data(), tangential_stiffness.typed_data(),
                  friction_coefficient.typed_data(), time_step.typed_data()[0], n, slots, force,
                  new_spring->typed_data(), torque_i, torque_j);
  T* total = totals->typed_data();
  std::fill(total, total + 6 * n, T(0));
  // As the reference's one segment sum: first every slot's share of j, then every slot's share of i.
  for (int64_t k = 0; k < slots; ++k) {
    if (id[k] >= n) continue;
    T* row = total + 6 * int64_t(id[slots + k]);
    for (int c = 0; c < 3; ++c) {
      row[c] += force[3 * k + c];
      row[3 + c] += torque_j[3 * k + c];
    }
  }
  for (int64_t k = 0; k < slots; ++k) {
    if (id[k] >= n) continue;
    T* row = total + 6 * int64_t(id[k]);
    for (int c = 0; c < 3; ++c) {
      row[c] -= force[3 * k + c];
      row[3 + c] += torque_i[3 * k + c];
    }
  }
  return ffi::Error::Success();
}

}  // namespace

#define MEMBRAX_DEM_PAIRS_HANDLER(name, dtype)                 \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(name, dem_pairs<dtype>,         \
                                ffi::Ffi::Bind()                \
                                    .Arg<ffi::Buffer<dtype>>()  \
                                    .Arg<ffi::Buffer<dtype>>()  \
                                    .Arg<ffi::Buffer<dtype>>()  \
                                    .Arg<ffi::Buffer<dtype>>()  \
                                    .Arg<ffi::Buffer<dtype>>()  \
                                    .Arg<ffi::Buffer<ffi::S32>>() \
                                    .Arg<ffi::Buffer<dtype>>()  \
                                    .Arg<ffi::Buffer<dtype>>()  \
                                    .Arg<ffi::Buffer<dtype>>()  \
                                    .Arg<ffi::Buffer<dtype>>()  \
                                    .Arg<ffi::Buffer<dtype>>()  \
                                    .Ret<ffi::Buffer<dtype>>()  \
                                    .Ret<ffi::Buffer<dtype>>()  \
                                    .Ret<ffi::Buffer<dtype>>());

MEMBRAX_DEM_PAIRS_HANDLER(MembraxDemPairsF32, ffi::F32)
MEMBRAX_DEM_PAIRS_HANDLER(MembraxDemPairsF64, ffi::F64)
