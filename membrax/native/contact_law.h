// The Cundall–Strack contact law shared by the kernels: the tangential spring and the sphere–sphere law.
//
// membrax.contact.tangential_spring_update is the reference:
//   s' = |s| Π_t(s)/max(|Π_t(s)|, |s|/2) − k_t Δt v_t, then s'' = s' min(1, μ F_n/|s'|); s'' = 0 if not in contact.
// Branch-free (selects only) and on 3-vectors passed by value, so that a loop calling it vectorises.

#ifndef MEMBRAX_NATIVE_CONTACT_LAW_H_
#define MEMBRAX_NATIVE_CONTACT_LAW_H_

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace membrax {

template <typename T>
struct Vec3 {
  T x, y, z;
};

template <typename T>
__attribute__((always_inline)) inline Vec3<T> operator+(Vec3<T> a, Vec3<T> b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
template <typename T>
__attribute__((always_inline)) inline Vec3<T> operator-(Vec3<T> a, Vec3<T> b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
template <typename T>
__attribute__((always_inline)) inline Vec3<T> operator*(T k, Vec3<T> a) { return {k * a.x, k * a.y, k * a.z}; }
template <typename T>
__attribute__((always_inline)) inline T dot(Vec3<T> a, Vec3<T> b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
template <typename T>
__attribute__((always_inline)) inline Vec3<T> cross(Vec3<T> a, Vec3<T> b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}

// Row i of an (n, 3) array.
template <typename T>
__attribute__((always_inline)) inline Vec3<T> row3(const T* a, int64_t i) {
  return {a[3 * i], a[3 * i + 1], a[3 * i + 2]};
}

// Entry k of the three component-first rows q, q + 1, q + 2 of `rows` (count entries each): the backward
// kernels' gathered inputs and per-slot shares.
template <typename T>
__attribute__((always_inline)) inline Vec3<T> column3(const T* rows, int q, int64_t count, int64_t k) {
  return {rows[q * count + k], rows[(q + 1) * count + k], rows[(q + 2) * count + k]};
}

// Adds value to row `plus` of an (n, 3) array and subtracts it from row `minus` (an action and its
// reaction on the two bodies of a contact).
template <typename T>
__attribute__((always_inline)) inline void add_opposite(T* a, int64_t plus, int64_t minus, Vec3<T> value) {
  a[3 * plus] += value.x;
  a[3 * plus + 1] += value.y;
  a[3 * plus + 2] += value.z;
  a[3 * minus] -= value.x;
  a[3 * minus + 1] -= value.y;
  a[3 * minus + 2] -= value.z;
}

// Adds value to row i of an (n, 3) array.
template <typename T>
__attribute__((always_inline)) inline void add3(T* a, int64_t i, Vec3<T> value) {
  a[3 * i] += value.x;
  a[3 * i + 1] += value.y;
  a[3 * i + 2] += value.z;
}

// spring: the carried spring; normal: unit normal (or zero); tangential_velocity: v_t;
// stiffness_dt: k_t Δt; limit: μ |F_n|; active: whether the bodies overlap. Returns the new spring.
template <typename T>
__attribute__((always_inline)) inline Vec3<T> tangential_spring(Vec3<T> spring, Vec3<T> normal, Vec3<T> tangential_velocity, T stiffness_dt,
                                 T limit, bool active) {
  const T length = std::sqrt(dot(spring, spring));
  const Vec3<T> projected = spring - dot(spring, normal) * normal;
  // Rotated into the tangent plane with its length kept; the rescaling is capped at 2 (a spring more than
  // 60° out of the plane is round-off, e.g. 1e-18 N along the normal of an FCC contact), as in the JAX law.
  const T denominator_sq = std::max(dot(projected, projected), T(0.25) * length * length);
  const T rotate = denominator_sq > T(0) ? length / std::sqrt(denominator_sq > T(0) ? denominator_sq : T(1)) : T(0);
  const Vec3<T> trial = rotate * projected - stiffness_dt * tangential_velocity;
  const T trial_length = std::sqrt(dot(trial, trial));
  const T slip = trial_length > limit ? limit / (trial_length > T(0) ? trial_length : T(1)) : T(1);
  return (active ? slip : T(0)) * trial;
}

// The cotangents of tangential_spring's inputs (active: a touching contact) from the new spring's, run
// backwards by hand with the derivatives of the JAX law's guarded norms and selects; with the new spring
// itself (tangential_spring's value), which the forward pass recomputed here gives for free.
template <typename T>
struct SpringCotangents {
  Vec3<T> spring, normal, tangential_velocity;
  T stiffness_dt, limit;
  Vec3<T> new_spring;
};

template <typename T>
__attribute__((always_inline)) inline SpringCotangents<T> tangential_spring_backward(
    Vec3<T> spring, Vec3<T> normal, Vec3<T> tangential_velocity, T stiffness_dt, T limit, Vec3<T> new_spring_bar) {
  // Forward, keeping the intermediates.
  const T length_sq = dot(spring, spring);
  const bool long_enough = length_sq > T(0);
  const T length = long_enough ? std::sqrt(long_enough ? length_sq : T(1)) : T(0);
  const T spring_normal = dot(spring, normal);
  const Vec3<T> projected = spring - spring_normal * normal;
  const T projected_sq = dot(projected, projected);
  const T quarter = T(0.25) * length * length;
  const bool projected_wins = projected_sq >= quarter;
  const T denominator_sq = projected_wins ? projected_sq : quarter;
  const bool positive = denominator_sq > T(0);
  const T denominator = positive ? std::sqrt(positive ? denominator_sq : T(1)) : T(0);
  const T safe_denominator = positive ? denominator : T(1);
  const T inverse_denominator = positive ? T(1) / safe_denominator : T(0);
  const Vec3<T> direction = inverse_denominator * projected;
  const Vec3<T> trial = length * direction - stiffness_dt * tangential_velocity;
  const T trial_sq = dot(trial, trial);
  const bool moving = trial_sq > T(0);
  const T trial_length = moving ? std::sqrt(moving ? trial_sq : T(1)) : T(0);
  const bool slipping = trial_length > limit;
  const T safe_trial_length = trial_length > T(0) ? trial_length : T(1);
  const T slip = slipping ? limit / safe_trial_length : T(1);

  // Backward: the branches of the guarded norms and selects as selects, so that a loop calling this
  // vectorises.
  SpringCotangents<T> bar{};
  bar.new_spring = slip * trial;
  Vec3<T> trial_bar = slip * new_spring_bar;
  const T slip_bar = dot(new_spring_bar, trial);  // slip = limit/|trial| when slipping
  bar.limit = slipping ? slip_bar / safe_trial_length : T(0);
  // (Float selects only: GCC does not vectorise a select between two conditions.)
  const T trial_length_bar_slipping =
      trial_length > T(0) ? -slip_bar * limit / (safe_trial_length * safe_trial_length) : T(0);
  const T trial_length_bar = slipping ? trial_length_bar_slipping : T(0);
  trial_bar = trial_bar + (moving ? trial_length_bar / safe_trial_length : T(0)) * trial;
  T length_bar = dot(trial_bar, direction);
  const Vec3<T> direction_bar = length * trial_bar;
  bar.tangential_velocity = (-stiffness_dt) * trial_bar;
  bar.stiffness_dt = -dot(trial_bar, tangential_velocity);
  // direction = projected/√(denominator²)
  const T denominator_bar = -dot(direction_bar, projected) * inverse_denominator * inverse_denominator;
  const T denominator_sq_bar = positive ? denominator_bar / (T(2) * safe_denominator) : T(0);
  const Vec3<T> projected_bar =
      inverse_denominator * direction_bar + (projected_wins ? T(2) * denominator_sq_bar : T(0)) * projected;
  length_bar += projected_wins ? T(0) : denominator_sq_bar * T(0.5) * length;
  // projected = s − (s·n̂) n̂
  const T spring_normal_bar = -dot(projected_bar, normal);
  bar.normal = spring_normal_bar * spring - spring_normal * projected_bar;
  bar.spring = projected_bar + spring_normal_bar * normal +
               (long_enough ? length_bar / (long_enough ? length : T(1)) : T(0)) * spring;
  return bar;
}

// Sphere–sphere Cundall–Strack contact (membrax.contact.pair_contact is the reference), b = x_j − x_i:
//   δ = R_i + R_j − |b|, n̂ = b/|b|, F_n = k_n max(δ, 0) n̂ (on j),
//   arm_i = (R_i − δ/2) n̂, arm_j = −(R_j − δ/2) n̂,
//   v_t = Π_t[(v_j + ω_j × arm_j) − (v_i + ω_i × arm_i)], s' = tangential_spring(s, n̂, v_t, k_t Δt, μ|F_n|, δ > 0),
//   F = F_n + s' on j, torque arm_i × (−F) on i and arm_j × F on j.
template <typename T>
struct PairResult {
  Vec3<T> force_on_j, torque_on_i, torque_on_j, spring;
};

template <typename T>
__attribute__((always_inline)) inline PairResult<T> sphere_pair(Vec3<T> branch, Vec3<T> velocity_i,
                                                                Vec3<T> velocity_j, Vec3<T> angular_i,
                                                                Vec3<T> angular_j, T radius_i, T radius_j,
                                                                Vec3<T> spring, T normal_stiffness,
                                                                T tangential_stiffness, T friction, T dt) {
  const T distance_sq = dot(branch, branch);
  const bool apart = distance_sq > T(0);
  const T distance = std::sqrt(distance_sq);
  const T inverse_distance = apart ? T(1) / (apart ? distance : T(1)) : T(0);
  const T overlap = radius_i + radius_j - distance;
  const bool active = overlap > T(0);
  // |F_n| = k_n max(δ, 0) (zero at |b| = 0, where the guarded norm has a zero gradient)
  const T normal_force = apart ? normal_stiffness * (overlap > T(0) ? overlap : T(0)) : T(0);
  const Vec3<T> normal = inverse_distance * branch;
  const Vec3<T> arm_i = (radius_i - T(0.5) * overlap) * normal;
  const Vec3<T> arm_j = (-(radius_j - T(0.5) * overlap)) * normal;
  const Vec3<T> relative = (velocity_j + cross(angular_j, arm_j)) - (velocity_i + cross(angular_i, arm_i));
  const Vec3<T> tangential_velocity = relative - dot(relative, normal) * normal;
  const Vec3<T> updated = tangential_spring(spring, normal, tangential_velocity, tangential_stiffness * dt,
                                            friction * normal_force, active);
  const Vec3<T> force = normal_force * normal + updated;
  return {force, cross(arm_i, T(-1) * force), cross(arm_j, force), updated};
}

}  // namespace membrax

#endif  // MEMBRAX_NATIVE_CONTACT_LAW_H_
