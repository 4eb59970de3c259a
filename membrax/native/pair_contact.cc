// Sphere–sphere Cundall–Strack contacts: forces, torques and tangential springs, one vectorised pass.
//
// An XLA FFI handler for the CPU, compiled on first use by membrax/native.py; the law is that of
// membrax/contact.py (pair_contact), which remains the reference and supplies the derivatives. Per
// contact, with b = x_j − x_i:
//   δ = R_i + R_j − |b|, n̂ = b/|b|, F_n = k_n max(δ, 0) n̂ (on j),
//   arm_i = (R_i − δ/2) n̂, arm_j = −(R_j − δ/2) n̂,
//   v_t = Π_t[(v_j + ω_j × arm_j) − (v_i + ω_i × arm_i)], s' = tangential_spring(...) (contact_law.h),
//   F = F_n + s' on j, torque arm_i × (−F) on i and arm_j × F on j.
//
// Inputs (T: float or double), component-first like the JAX law: branch, velocity_i, velocity_j,
// angular_velocity_i, angular_velocity_j (3, C); radius_i, radius_j (C,); spring (3, C); normal_stiffness,
// tangential_stiffness, friction_coefficient (C,); dt (1,).
// Outputs: force_on_j, torque_on_i, torque_on_j, spring' (3, C).

#include <algorithm>
#include <cmath>
#include <cstdint>

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
  using Vec3 = membrax::Vec3<T>;
  using membrax::cross;
  using membrax::dot;
#pragma GCC ivdep
  for (int64_t k = 0; k < n; ++k) {
    const Vec3 x = load(b, n, k);
    const T distance_sq = dot(x, x);
    const bool apart = distance_sq > T(0);
    const T distance = std::sqrt(distance_sq);
    const T inverse_distance = apart ? T(1) / (apart ? distance : T(1)) : T(0);
    const T overlap = ri[k] + rj[k] - distance;
    const bool active = overlap > T(0);
    // |F_n| = k_n max(δ, 0) (zero at |b| = 0, where the guarded norm has a zero gradient)
    const T normal_force = apart ? kn[k] * (overlap > T(0) ? overlap : T(0)) : T(0);
    const Vec3 normal = inverse_distance * x;
    const Vec3 arm_i = (ri[k] - T(0.5) * overlap) * normal;
    const Vec3 arm_j = (-(rj[k] - T(0.5) * overlap)) * normal;
    const Vec3 relative =
        (load(vj, n, k) + cross(load(wj, n, k), arm_j)) - (load(vi, n, k) + cross(load(wi, n, k), arm_i));
    const Vec3 tangential_velocity = relative - dot(relative, normal) * normal;
    const Vec3 updated = membrax::tangential_spring(load(s, n, k), normal, tangential_velocity, kt[k] * dt,
                                                    mu[k] * normal_force, active);
    const Vec3 f = normal_force * normal + updated;
    store(force, n, k, f);
    store(torque_i, n, k, cross(arm_i, T(-1) * f));
    store(torque_j, n, k, cross(arm_j, f));
    store(springs, n, k, updated);
  }
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
