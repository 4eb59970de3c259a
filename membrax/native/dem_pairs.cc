// The DEM's sphere–sphere contacts over a neighbour list, summed per sphere, in one pass.
//
// An XLA FFI handler for the CPU (asynchronous: the law runs in two halves of the slots as tasks on XLA's
// thread pool, parallel.h), compiled on first use by membrax/native/__init__.py. For each slot (i, j) =
// idx[:, k] (padded with N) it gathers the two spheres (b = (x_j − x_i) + (c_j − c_i), positions with
// their compensation), applies the Cundall–Strack law (contact_law.h, sphere_pair; the reference is
// membrax.spheres.contact.pair_contact), zeroes the padded slots and sums per sphere: j receives (F, T_j), i
// receives (−F, T_i). membrax/spheres/integrate.py (_pair_totals_reference) is the JAX definition;
// dem_pairs_backward (below) is its reverse-mode rule.
//
// Inputs (T: float or double): position, compensation, velocity, angular_velocity (N, 3); radius (N,);
// idx (2, C) i32 padded with N; spring (C, 3); normal_stiffness, tangential_stiffness,
// friction_coefficient (C,); dt (1,). Outputs: totals (N, 6) force and torque per sphere; spring' and the
// force on j (C, 3), zero on padded slots.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "contact_law.h"
#include "parallel.h"
#include "ffi_bind.h"
#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

// Pass 1, vectorised: gather, law and per-slot outputs (padded slots zeroed).
template <typename T>
void dem_pair_law(const T* __restrict position, const T* __restrict compensation, const T* __restrict velocity,
                  const T* __restrict angular, const T* __restrict radius, const int32_t* __restrict idx,
                  const T* __restrict spring, const T* __restrict kn, const T* __restrict kt,
                  const T* __restrict mu, T dt, int64_t num_spheres, int64_t num_slots, int64_t begin, int64_t end,
                  T* __restrict pair_force, T* __restrict new_spring, T* __restrict torque_i,
                  T* __restrict torque_j) {
  using Vec3 = membrax::Vec3<T>;
#pragma GCC ivdep
  for (int64_t k = begin; k < end; ++k) {
    const int32_t i = idx[k], j = idx[num_slots + k];
    const bool valid = i < num_spheres;
    const int64_t gi = valid ? i : 0, gj = valid ? j : 0;
    using membrax::row3;
    const Vec3 branch = (row3(position, gj) - row3(position, gi)) + (row3(compensation, gj) - row3(compensation, gi));
    const auto result = membrax::sphere_pair(branch, row3(velocity, gi), row3(velocity, gj), row3(angular, gi),
                                             row3(angular, gj), radius[gi], radius[gj], row3(spring, k), kn[k],
                                             kt[k], mu[k], dt);
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

// dem_pairs' inputs, which its backward takes too: N spheres, C slots and the arrays' data (Δt's value);
// `error` is nullptr when the sizes agree, else what is wrong (and the rest zero).
template <typename T>
struct PairInputs {
  const char* error;
  int64_t n, slots;
  const T *x, *xc, *v, *w, *r, *spring, *kn, *kt, *mu;
  T dt;
  const int32_t* id;
};

template <ffi::DataType dtype>
PairInputs<ffi::NativeType<dtype>> pair_inputs(
    const ffi::Buffer<dtype>& position, const ffi::Buffer<dtype>& compensation, const ffi::Buffer<dtype>& velocity,
    const ffi::Buffer<dtype>& angular_velocity, const ffi::Buffer<dtype>& radius, const ffi::Buffer<ffi::S32>& idx,
    const ffi::Buffer<dtype>& spring, const ffi::Buffer<dtype>& normal_stiffness,
    const ffi::Buffer<dtype>& tangential_stiffness, const ffi::Buffer<dtype>& friction_coefficient,
    const ffi::Buffer<dtype>& time_step) {
  const int64_t n = radius.element_count(), slots = spring.element_count() / 3;
  for (const auto* rows : {&position, &compensation, &velocity, &angular_velocity}) {
    if (rows->element_count() != size_t(3 * n)) return {"sphere arrays must be (N, 3) with N the radii's length"};
  }
  for (const auto* scalar : {&normal_stiffness, &tangential_stiffness, &friction_coefficient}) {
    if (scalar->element_count() != size_t(slots)) return {"per-slot parameters must be (C,)"};
  }
  if (idx.element_count() != size_t(2 * slots)) return {"idx must be (2, C)"};
  if (time_step.element_count() != 1) return {"time_step must be (1,)"};
  return {nullptr, n, slots, position.typed_data(), compensation.typed_data(), velocity.typed_data(),
          angular_velocity.typed_data(), radius.typed_data(), spring.typed_data(), normal_stiffness.typed_data(),
          tangential_stiffness.typed_data(), friction_coefficient.typed_data(), time_step.typed_data()[0],
          idx.typed_data()};
}

template <ffi::DataType dtype>
ffi::Future dem_pairs(ffi::Buffer<dtype> position, ffi::Buffer<dtype> compensation, ffi::Buffer<dtype> velocity,
                      ffi::Buffer<dtype> angular_velocity, ffi::Buffer<dtype> radius, ffi::Buffer<ffi::S32> idx,
                      ffi::Buffer<dtype> spring, ffi::Buffer<dtype> normal_stiffness,
                      ffi::Buffer<dtype> tangential_stiffness, ffi::Buffer<dtype> friction_coefficient,
                      ffi::Buffer<dtype> time_step, ffi::ResultBuffer<dtype> totals,
                      ffi::ResultBuffer<dtype> new_spring, ffi::ResultBuffer<dtype> pair_force,
                      ffi::ThreadPool pool) {
  using T = ffi::NativeType<dtype>;
  const PairInputs<T> in = pair_inputs(position, compensation, velocity, angular_velocity, radius, idx, spring,
                                       normal_stiffness, tangential_stiffness, friction_coefficient, time_step);
  if (in.error) return membrax::failed(ffi::Error::InvalidArgument(std::string("dem_pairs: ") + in.error));
  const int64_t n = in.n, slots = in.slots;
  const int32_t* id = in.id;
  T* force = pair_force->typed_data();
  T* springs = new_spring->typed_data();
  T* total = totals->typed_data();
  // The law in two halves of the slots (parallel.h, half_range), each writing its own slots' outputs and
  // torques; then the per-sphere sums in slot order, once both are done: the bits of one pass.
  std::shared_ptr<T[]> scratch(new T[size_t(6 * slots)]);
  auto half = [=](int h) {
    const membrax::Range range = membrax::half_range(h, slots);
    T* torque_i = scratch.get();
    dem_pair_law<T>(in.x, in.xc, in.v, in.w, in.r, id, in.spring, in.kn, in.kt, in.mu, in.dt, n, slots,
                    range.begin, range.end, force, springs, torque_i, torque_i + 3 * slots);
  };
  auto tail = [=]() {
    const T* torque_i = scratch.get();
    const T* torque_j = torque_i + 3 * slots;
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
  };
  return membrax::halves_on_pool(pool, slots, half, tail);
}


// ---- The backward kernel: sphere_pair run backwards by hand for each touching slot.

// The backward's per-slot rows (component-first, C entries each): what pass 0 gathers from the two
// spheres, and the shares of the spheres and of Δt that pass 2 sums.
enum PairGathered { kBranchIn = 0, kVelocityI = 3, kVelocityJ = 6, kAngularIIn = 9, kAngularJIn = 12,
                    kForceBar = 15, kTorqueIBar = 18, kTorqueJBar = 21, kRadiusIIn = 24, kRadiusJIn, kGathered };
enum PairShare { kBranch = 0, kRelative = 3, kAngularI = 6, kAngularJ = 9, kRadiusI = 12, kRadiusJ, kDt, kShares };

// Pass 0, serial: each slot's inputs from its two spheres (zeros on padded slots, which the law then
// treats as not touching), so that pass 1 reads contiguous rows; GCC does not vectorise a loop with
// that many gathers.
template <typename T>
void dem_pair_gather(const T* x, const T* xc, const T* v, const T* w, const T* r, const int32_t* id,
                     const T* total_bar, int64_t n, int64_t slots, int64_t begin, int64_t end, T* gathered) {
  for (int64_t k = begin; k < end; ++k) {
    const int64_t i = id[k], j = id[slots + k];
    const bool valid = i < n;
    for (int c = 0; c < 3; ++c) {
      gathered[(kBranchIn + c) * slots + k] = valid ? (x[3 * j + c] - x[3 * i + c]) + (xc[3 * j + c] - xc[3 * i + c]) : T(0);
      gathered[(kVelocityI + c) * slots + k] = valid ? v[3 * i + c] : T(0);
      gathered[(kVelocityJ + c) * slots + k] = valid ? v[3 * j + c] : T(0);
      gathered[(kAngularIIn + c) * slots + k] = valid ? w[3 * i + c] : T(0);
      gathered[(kAngularJIn + c) * slots + k] = valid ? w[3 * j + c] : T(0);
      gathered[(kForceBar + c) * slots + k] = valid ? total_bar[6 * j + c] - total_bar[6 * i + c] : T(0);
      gathered[(kTorqueIBar + c) * slots + k] = valid ? total_bar[6 * i + 3 + c] : T(0);
      gathered[(kTorqueJBar + c) * slots + k] = valid ? total_bar[6 * j + 3 + c] : T(0);
    }
    gathered[kRadiusIIn * slots + k] = valid ? r[i] : T(0);
    gathered[kRadiusJIn * slots + k] = valid ? r[j] : T(0);
  }
}

// Pass 1 of the backward, vectorised: the law of every slot run backwards (branch-free; padded slots and
// slots that do not touch, δ ≤ 0, give zeros). The per-slot cotangents (spring, k_n, k_t, μ) are written
// out; the shares of the spheres and of Δt go to `share` for pass 2's sums. (Not inlined, as
// node_sphere.cc's slot_laws_backward: inlined into a handler, GCC 12 may leave such a loop scalar.)
template <typename T>
__attribute__((noinline)) void dem_pair_law_backward(const T* __restrict in, const T* __restrict s_in, const T* __restrict kn,
                           const T* __restrict kt, const T* __restrict mu, T dt, const T* __restrict s_bar,
                           const T* __restrict f_bar, int64_t slots, int64_t begin, int64_t end,
                           T* __restrict s_out, T* __restrict kn_bar, T* __restrict kt_bar, T* __restrict mu_bar,
                           T* __restrict share) {
  using Vec3 = membrax::Vec3<T>;
  using membrax::cross;
  using membrax::dot;
  using membrax::row3;
  auto row = [slots, in](int q, int64_t k) { return membrax::column3(in, q, slots, k); };
#pragma GCC ivdep
  for (int64_t k = begin; k < end; ++k) {
    // Forward (sphere_pair), keeping the intermediates.
    const Vec3 branch = row(kBranchIn, k);
    const T radius_i = in[kRadiusIIn * slots + k], radius_j = in[kRadiusJIn * slots + k];
    const T distance_sq = dot(branch, branch);
    const bool apart = distance_sq > T(0);
    const T distance = std::sqrt(apart ? distance_sq : T(1));
    const T overlap = radius_i + radius_j - distance;
    const bool active = (apart ? overlap : T(0)) > T(0);
    const Vec3 normal = (T(1) / distance) * branch;
    const T normal_force = kn[k] * overlap;
    const Vec3 arm_i = (radius_i - T(0.5) * overlap) * normal;
    const Vec3 arm_j = (-(radius_j - T(0.5) * overlap)) * normal;
    const Vec3 wi = row(kAngularIIn, k), wj = row(kAngularJIn, k);
    const Vec3 relative = (row(kVelocityJ, k) + cross(wj, arm_j)) - (row(kVelocityI, k) + cross(wi, arm_i));
    const T normal_speed = dot(relative, normal);
    const Vec3 tangential_velocity = relative - normal_speed * normal;
    // The outputs' cotangents: F on j (totals of j, less those of i, and the pair force), torques
    // τ_i = −arm_i × F and τ_j = arm_j × F, spring s'.
    const Vec3 torque_i_bar = row(kTorqueIBar, k), torque_j_bar = row(kTorqueJBar, k);
    const Vec3 force_bar =
        row(kForceBar, k) + row3(f_bar, k) + cross(arm_i, torque_i_bar) + cross(torque_j_bar, arm_j);
    // F = F_n n̂ + s'
    T normal_force_bar = dot(force_bar, normal);
    const membrax::SpringCotangents<T> bar = membrax::tangential_spring_backward(
        row3(s_in, k), normal, tangential_velocity, kt[k] * dt, mu[k] * normal_force, row3(s_bar, k) + force_bar);
    const Vec3 force = normal_force * normal + bar.new_spring;
    Vec3 arm_i_bar = cross(torque_i_bar, force);
    Vec3 arm_j_bar = cross(force, torque_j_bar);
    Vec3 normal_bar = normal_force * force_bar + bar.normal;
    normal_force_bar += bar.limit * mu[k];
    // v_t = v − (v·n̂) n̂
    const T normal_speed_bar = -dot(bar.tangential_velocity, normal);
    normal_bar = normal_bar - normal_speed * bar.tangential_velocity + normal_speed_bar * relative;
    const Vec3 relative_bar = bar.tangential_velocity + normal_speed_bar * normal;
    // v_rel = v_j + ω_j × arm_j − v_i − ω_i × arm_i
    arm_j_bar = arm_j_bar + cross(relative_bar, wj);
    arm_i_bar = arm_i_bar - cross(relative_bar, wi);
    const Vec3 angular_j_bar = cross(arm_j, relative_bar);
    const Vec3 angular_i_bar = T(-1) * cross(arm_i, relative_bar);
    // arm_i = (R_i − δ/2) n̂, arm_j = −(R_j − δ/2) n̂
    const T along_i = dot(arm_i_bar, normal), along_j = dot(arm_j_bar, normal);
    normal_bar = normal_bar + (radius_i - T(0.5) * overlap) * arm_i_bar - (radius_j - T(0.5) * overlap) * arm_j_bar;
    // F_n = k_n δ; δ = R_i + R_j − |b|, n̂ = b/|b|
    const T overlap_bar = T(-0.5) * along_i + T(0.5) * along_j + normal_force_bar * kn[k];
    const Vec3 branch_bar =
        (T(1) / distance) * (normal_bar - dot(normal_bar, normal) * normal) - overlap_bar * normal;
    // Selects, not products with a 0/1 mask: an untouching slot's values may be inf or NaN.
    auto keep = [active](T value) { return active ? value : T(0); };
    s_out[3 * k] = keep(bar.spring.x);
    s_out[3 * k + 1] = keep(bar.spring.y);
    s_out[3 * k + 2] = keep(bar.spring.z);
    kn_bar[k] = keep(normal_force_bar * overlap);
    kt_bar[k] = keep(bar.stiffness_dt * dt);
    mu_bar[k] = keep(bar.limit * normal_force);
    const T shares[kShares] = {branch_bar.x,    branch_bar.y,    branch_bar.z,    relative_bar.x,  relative_bar.y,
                               relative_bar.z,  angular_i_bar.x, angular_i_bar.y, angular_i_bar.z, angular_j_bar.x,
                               angular_j_bar.y, angular_j_bar.z, along_i + overlap_bar, -along_j + overlap_bar,
                               bar.stiffness_dt * kt[k]};
#pragma GCC unroll 32
    for (int q = 0; q < kShares; ++q) share[q * slots + k] = keep(shares[q]);
  }
}

// Inputs: those of dem_pairs, then the cotangents of its outputs: totals (N, 6), spring' and the force
// on j (C, 3). Outputs: the cotangents of position and compensation (N, 3, equal: b = (x_j − x_i) +
// (c_j − c_i)), velocity and angular velocity (N, 3), radius (N,), spring (C, 3), the per-slot k_n, k_t,
// μ (C,) and Δt (1,). Padded slots and slots that do not touch (δ ≤ 0: zero outputs) contribute nothing.
template <ffi::DataType dtype>
ffi::Error dem_pairs_backward(ffi::Buffer<dtype> position, ffi::Buffer<dtype> compensation,
                              ffi::Buffer<dtype> velocity, ffi::Buffer<dtype> angular_velocity,
                              ffi::Buffer<dtype> radius, ffi::Buffer<ffi::S32> idx, ffi::Buffer<dtype> spring,
                              ffi::Buffer<dtype> normal_stiffness, ffi::Buffer<dtype> tangential_stiffness,
                              ffi::Buffer<dtype> friction_coefficient, ffi::Buffer<dtype> time_step,
                              ffi::Buffer<dtype> totals_bar, ffi::Buffer<dtype> spring_bar,
                              ffi::Buffer<dtype> pair_force_bar, ffi::ResultBuffer<dtype> position_out,
                              ffi::ResultBuffer<dtype> velocity_out, ffi::ResultBuffer<dtype> angular_out,
                              ffi::ResultBuffer<dtype> radius_out, ffi::ResultBuffer<dtype> spring_out,
                              ffi::ResultBuffer<dtype> kn_out, ffi::ResultBuffer<dtype> kt_out,
                              ffi::ResultBuffer<dtype> mu_out, ffi::ResultBuffer<dtype> dt_out, ffi::ThreadPool pool) {
  using T = ffi::NativeType<dtype>;
  const PairInputs<T> in = pair_inputs(position, compensation, velocity, angular_velocity, radius, idx, spring,
                                       normal_stiffness, tangential_stiffness, friction_coefficient, time_step);
  if (in.error) return ffi::Error::InvalidArgument(std::string("dem_pairs_backward: ") + in.error);
  const int64_t n = in.n, slots = in.slots;
  if (totals_bar.element_count() != size_t(6 * n) ||
      spring_bar.element_count() != size_t(3 * slots) || pair_force_bar.element_count() != size_t(3 * slots))
    return ffi::Error::InvalidArgument("dem_pairs_backward: inconsistent array sizes");
  const int32_t* id = in.id;
  thread_local std::vector<T> scratch;
  scratch.resize(size_t((kGathered + kShares) * slots));
  T* gathered = scratch.data();
  T* share = gathered + kGathered * slots;
  // Passes 0 and 1 in two halves on two threads (parallel.h); each half writes its own slots.
  membrax::two_halves(pool, slots, [&](int, int64_t begin, int64_t end) {
    dem_pair_gather<T>(in.x, in.xc, in.v, in.w, in.r, id, totals_bar.typed_data(), n, slots, begin, end, gathered);
    dem_pair_law_backward<T>(gathered, in.spring, in.kn, in.kt, in.mu, in.dt, spring_bar.typed_data(),
                             pair_force_bar.typed_data(), slots, begin, end, spring_out->typed_data(),
                             kn_out->typed_data(), kt_out->typed_data(), mu_out->typed_data(), share);
  });
  // Pass 2, in slot order: each slot's shares to its two spheres.
  T* x_out = position_out->typed_data();
  T* v_out = velocity_out->typed_data();
  T* w_out = angular_out->typed_data();
  T* r_out = radius_out->typed_data();
  std::fill(x_out, x_out + 3 * n, T(0));
  std::fill(v_out, v_out + 3 * n, T(0));
  std::fill(w_out, w_out + 3 * n, T(0));
  std::fill(r_out, r_out + n, T(0));
  T dt_bar = T(0);
  for (int64_t k = 0; k < slots; ++k) {
    const int64_t i = id[k], j = id[slots + k];
    if (i >= n) continue;
    membrax::add_opposite(x_out, j, i, membrax::column3(share, kBranch, slots, k));
    membrax::add_opposite(v_out, j, i, membrax::column3(share, kRelative, slots, k));
    membrax::add3(w_out, i, membrax::column3(share, kAngularI, slots, k));
    membrax::add3(w_out, j, membrax::column3(share, kAngularJ, slots, k));
    r_out[i] += share[kRadiusI * slots + k];
    r_out[j] += share[kRadiusJ * slots + k];
    dt_bar += share[kDt * slots + k];
  }
  dt_out->typed_data()[0] = dt_bar;
  return ffi::Error::Success();
}

}  // namespace

MEMBRAX_DEFINE_HANDLERS(MembraxDemPairs, dem_pairs);
MEMBRAX_DEFINE_HANDLERS(MembraxDemPairsBackward, dem_pairs_backward);
