// Sphere–sphere Cundall–Strack contacts: the law alone, and the DEM's pair forces summed per sphere.
//
// XLA FFI handlers for the CPU, compiled on first use by membrax/native.py. The law (contact_law.h,
// sphere_pair) is that of membrax/contact.py (pair_contact), which remains the reference and supplies
// the derivatives.
//
// pair_contact: one vectorised pass over component-first contacts, like the JAX law. Inputs (T: float
// or double): branch, velocity_i, velocity_j, angular_velocity_i, angular_velocity_j (3, C); radius_i,
// radius_j (C,); spring (3, C); normal_stiffness, tangential_stiffness, friction_coefficient (C,); dt (1,).
// Outputs: force_on_j, torque_on_i, torque_on_j, spring' (3, C).
//
// dem_pairs: gather, law and per-sphere sums over a neighbour list (membrax/integrate.py,
// _pair_totals_reference). Inputs: position, compensation, velocity, angular_velocity (N, 3); radius
// (N,); idx (2, C) i32 padded with N; spring (C, 3); normal_stiffness, tangential_stiffness,
// friction_coefficient (C,); dt (1,). Outputs: totals (N, 6) force and torque per sphere; spring' and
// the force on j (C, 3), zero on padded slots.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "contact_law.h"
#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

// Entry k of a component-first (3, n) array, and its store.
template <typename T>
__attribute__((always_inline)) inline membrax::Vec3<T> load(const T* __restrict a, int64_t n, int64_t k) {
  return {a[k], a[n + k], a[2 * n + k]};
}

template <typename T>
__attribute__((always_inline)) inline void store(T* __restrict a, int64_t n, int64_t k, membrax::Vec3<T> v) {
  a[k] = v.x;
  a[n + k] = v.y;
  a[2 * n + k] = v.z;
}

template <typename T>
void pair_law(const T* __restrict b, const T* __restrict vi, const T* __restrict vj, const T* __restrict wi,
              const T* __restrict wj, const T* __restrict ri, const T* __restrict rj, const T* __restrict s,
              const T* __restrict kn, const T* __restrict kt, const T* __restrict mu, T dt, int64_t n,
              T* __restrict force, T* __restrict torque_i, T* __restrict torque_j, T* __restrict springs) {
#pragma GCC ivdep
  for (int64_t k = 0; k < n; ++k) {
    const auto result = membrax::sphere_pair(load(b, n, k), load(vi, n, k), load(vj, n, k), load(wi, n, k),
                                             load(wj, n, k), ri[k], rj[k], load(s, n, k), kn[k], kt[k], mu[k], dt);
    store(force, n, k, result.force_on_j);
    store(torque_i, n, k, result.torque_on_i);
    store(torque_j, n, k, result.torque_on_j);
    store(springs, n, k, result.spring);
  }
}

// The DEM's pair forces (membrax.integrate._pair_totals_reference): for each neighbour-list slot
// (i, j) = idx[:, k] (padded with N), gather the two spheres (positions with their compensation, b =
// (x_j − x_i) + (c_j − c_i)), apply the law, zero the padded slots, and sum per sphere: j receives
// (F, T_j), i receives (−F, T_i).
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

template <ffi::DataType dtype>
ffi::Error pair_contact(ffi::Buffer<dtype> branch, ffi::Buffer<dtype> velocity_i, ffi::Buffer<dtype> velocity_j,
                        ffi::Buffer<dtype> angular_velocity_i, ffi::Buffer<dtype> angular_velocity_j,
                        ffi::Buffer<dtype> radius_i, ffi::Buffer<dtype> radius_j, ffi::Buffer<dtype> spring,
                        ffi::Buffer<dtype> normal_stiffness, ffi::Buffer<dtype> tangential_stiffness,
                        ffi::Buffer<dtype> friction_coefficient, ffi::Buffer<dtype> time_step,
                        ffi::ResultBuffer<dtype> force_on_j, ffi::ResultBuffer<dtype> torque_on_i,
                        ffi::ResultBuffer<dtype> torque_on_j, ffi::ResultBuffer<dtype> new_spring) {
  using T = ffi::NativeType<dtype>;
  const int64_t n = radius_i.element_count();
  for (const auto* vector : {&branch, &velocity_i, &velocity_j, &angular_velocity_i, &angular_velocity_j, &spring}) {
    if (vector->element_count() != size_t(3 * n))
      return ffi::Error::InvalidArgument("pair_contact: vectors must be (3, C) with C the radii's length");
  }
  for (const auto* scalar : {&radius_j, &normal_stiffness, &tangential_stiffness, &friction_coefficient}) {
    if (scalar->element_count() != size_t(n))
      return ffi::Error::InvalidArgument("pair_contact: per-contact scalars must be (C,)");
  }
  pair_law<T>(branch.typed_data(), velocity_i.typed_data(), velocity_j.typed_data(),
              angular_velocity_i.typed_data(), angular_velocity_j.typed_data(), radius_i.typed_data(),
              radius_j.typed_data(), spring.typed_data(), normal_stiffness.typed_data(),
              tangential_stiffness.typed_data(), friction_coefficient.typed_data(), time_step.typed_data()[0], n,
              force_on_j->typed_data(), torque_on_i->typed_data(), torque_on_j->typed_data(),
              new_spring->typed_data());
  return ffi::Error::Success();
}

}  // namespace

#define MEMBRAX_PAIR_HANDLER(name, dtype)                     \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(name, pair_contact<dtype>,    \
                                ffi::Ffi::Bind()              \
                                    .Arg<ffi::Buffer<dtype>>() \
                                    .Arg<ffi::Buffer<dtype>>() \
                                    .Arg<ffi::Buffer<dtype>>() \
                                    .Arg<ffi::Buffer<dtype>>() \
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

MEMBRAX_PAIR_HANDLER(MembraxPairContactF32, ffi::F32)
MEMBRAX_PAIR_HANDLER(MembraxPairContactF64, ffi::F64)

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
