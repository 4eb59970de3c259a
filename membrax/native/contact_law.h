// The tangential spring of the Cundall–Strack law, shared by the sphere–sphere and node–sphere kernels.
//
// membrax.contact.tangential_spring_update is the reference:
//   s' = |s| Π_t(s)/|Π_t(s)| − k_t Δt v_t, then s'' = s' min(1, μ F_n/|s'|); s'' = 0 if not in contact.
// Branch-free (selects only) and on 3-vectors passed by value, so that a loop calling it vectorises.

#ifndef MEMBRAX_NATIVE_CONTACT_LAW_H_
#define MEMBRAX_NATIVE_CONTACT_LAW_H_

#include <cmath>

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

// spring: the carried spring; normal: unit normal (or zero); tangential_velocity: v_t;
// stiffness_dt: k_t Δt; limit: μ |F_n|; active: whether the bodies overlap. Returns the new spring.
template <typename T>
__attribute__((always_inline)) inline Vec3<T> tangential_spring(Vec3<T> spring, Vec3<T> normal, Vec3<T> tangential_velocity, T stiffness_dt,
                                 T limit, bool active) {
  const T length = std::sqrt(dot(spring, spring));
  const Vec3<T> projected = spring - dot(spring, normal) * normal;
  const T projected_sq = dot(projected, projected);
  // Rotated into the tangent plane with its length kept (zero if the spring stood along the normal).
  const T rotate = projected_sq > T(0) ? length / std::sqrt(projected_sq > T(0) ? projected_sq : T(1)) : T(0);
  const Vec3<T> trial = rotate * projected - stiffness_dt * tangential_velocity;
  const T trial_length = std::sqrt(dot(trial, trial));
  const T slip = trial_length > limit ? limit / (trial_length > T(0) ? trial_length : T(1)) : T(1);
  return (active ? slip : T(0)) * trial;
}

}  // namespace membrax

#endif  // MEMBRAX_NATIVE_CONTACT_LAW_H_
